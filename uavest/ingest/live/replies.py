"""Replies to the live link's requests: COMMAND_ACKs and PARAM_VALUEs put by the reader
thread and awaited by the setup steps (timeouts in seconds, monotonic clock)."""

from __future__ import annotations

import threading
import time
from collections import deque


class Replies:
    """COMMAND_ACKs and PARAM_VALUEs put by the reader thread, awaited by the setup steps."""

    def __init__(self) -> None:
        self.cond = threading.Condition()
        self.acks: deque = deque(maxlen=64)  # (command, result, monotonic time)
        self.params: dict[str, float] = {}

    def ack(self, command: int, result: int) -> None:
        with self.cond:
            self.acks.append((command, result, time.monotonic()))
            self.cond.notify_all()

    def param(self, name: str, value: float) -> None:
        with self.cond:
            self.params[name] = value
            self.cond.notify_all()

    def forget(self, name: str) -> None:
        """Drop an earlier answer for ``name`` (before asking again)."""
        with self.cond:
            self.params.pop(name, None)

    def wait_ack(self, command: int, since: float, timeout: float) -> int | None:
        """The result of the first ACK of ``command`` received since ``since`` (monotonic
        s), None after ``timeout`` s."""
        end = time.monotonic() + timeout
        with self.cond:
            while True:
                for c, r, t in self.acks:
                    if c == command and t >= since:
                        self.acks.remove((c, r, t))
                        return r
                left = end - time.monotonic()
                if left <= 0:
                    return None
                self.cond.wait(left)

    def wait_param(self, name: str, timeout: float) -> float | None:
        """The value of parameter ``name``, None after ``timeout`` s."""
        end = time.monotonic() + timeout
        with self.cond:
            while name not in self.params:
                left = end - time.monotonic()
                if left <= 0:
                    return None
                self.cond.wait(left)
            return self.params[name]
