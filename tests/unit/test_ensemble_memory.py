"""benchmarks/ensemble_memory.py (docs/filters.md, "Long memory"): on the navigation
filter's position and velocity alone, linear and Gaussian, the Kalman filter is
consistent and an ensemble's position covariance shrinks below it, unless (the hybrid of
the navigation preset) it re-spreads its members after each shift; a filter's numbers do
not depend on what runs beside it."""

from __future__ import annotations

from conftest import load_benchmark


def test_the_ensembles_position_covariance_shrinks_below_the_kalman_filters():
    bench = load_benchmark("ensemble_memory")
    rows = bench.trial("ekf,enkf", 0, 0, 2000)  # (RMSE cm, std cm, NEES mean, in band)
    kf, enkf = rows["ekf"], rows["enkf"]
    assert kf[3] >= 0.8 and 1.0 < kf[2] < 5.0, kf  # the Kalman filter: consistent
    assert enkf[1] < 0.6 * kf[1] and enkf[2] > 3 * kf[2], (enkf, kf)
    assert bench.trial("enkf", 0, 0, 2000)["enkf"] == enkf  # its own random stream


def test_the_hybrids_respread_keeps_its_position_covariance_at_the_kalman_filters():
    bench = load_benchmark("ensemble_memory")
    rows = bench.trial("ekf,hybrid,hybrid(reinflate=false),hybrid(tau=1.0),"
                       "hybrid(tau=1.0,reinflate=false)", 0, 0, 2000)
    kf = rows["ekf"][1]  # position std, cm
    for on, off in (("hybrid", "hybrid(reinflate=false)"),
                    ("hybrid(tau=1.0)", "hybrid(tau=1.0,reinflate=false)")):
        assert 0.85 * kf < rows[on][1] < 1.2 * kf, (on, rows[on], kf)
        assert rows[off][1] < 0.75 * kf, (off, rows[off], kf)
