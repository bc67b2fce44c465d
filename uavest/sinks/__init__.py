"""Sinks: observers that receive every record the engine makes (tables, JSON, MCAP,
live view, MAVLink publisher). See :class:`uavest.sinks.base.Sink`."""
