"""Filter specs: parsing, validation (one-line errors naming filter, parameter, value and
what is allowed), presets (resolved parameters, user parameters win), JSON form, and the
compatibility wrappers (``make_filter``, ``make_filter_in_context``)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from uavest import presets
from uavest.core import (
    CKF,
    UKF,
    EnKF,
    FilterSpec,
    Gaussian,
    HybridLocal,
    HybridShift,
    SageHusa,
    SpecError,
    build,
    make_filter,
    make_filter_in_context,
    parse_filter_list,
    parse_spec,
)
from uavest.core.registry import REGISTRY, param_table

BAD = [
    ("ukf(alpha=abc)", "ukf: alpha must be a number > 0, got 'abc'"),
    ("ukf(alpha=nan)", "ukf: alpha must be a number > 0, got nan"),
    ("ukf(alpha=0)", "ukf: alpha must be a number > 0, got 0"),
    ("ukf(alpha=-inf)", "ukf: alpha must be a number > 0, got -inf"),
    ("hybrid(n_cloud=2.5)", "hybrid: n_cloud must be an integer >= 1, got 2.5"),
    ("hybrid(n_cloud=-1)", "hybrid: n_cloud must be an integer >= 1, got -1"),
    ("hybrid(n_cloud=0)", "hybrid: n_cloud must be an integer >= 1, got 0"),
    ("hybrid(n_cloud=true)", "hybrid: n_cloud must be an integer >= 1, got true"),
    ("enkf(members=1)", "enkf: members must be an integer >= 2, got 1"),
    ("hybrid_sh(b=5)", "hybrid_sh: b must be a number in (0, 1), got 5"),
    ("hybrid_sh(b=1)", "hybrid_sh: b must be a number in (0, 1), got 1"),
    ("ukf_sh(adapt=X)", "ukf_sh: adapt must be one of R, Q, RQ, got 'X'"),
    ("hybrid(tau=0)", "hybrid: tau must be a number in (0, 1], got 0"),
    ("hybrid(sampling=grid)", "hybrid: sampling must be one of expanded, random, got 'grid'"),
    ("hybrid(update_mode=global)",
     "hybrid: update_mode must be one of shift, local, got 'global'"),
    ("pf(resample_threshold=2)", "pf: resample_threshold must be a number in [0, 1], got 2"),
    ("ukf(nope=1)",
     "ukf: unknown parameter 'nope' (given nope=1); known: alpha, beta, kappa, points"),
    ("ckf(alpha=0.5)", "ckf: unknown parameter 'alpha'"),
    ("kalman_nine", "unknown filter 'kalman_nine'; known: kf, ekf, ukf, ckf"),
    ("kalman_nine_sh", "unknown filter 'kalman_nine'; known:"),
    ("hybrid(update_mode=local, tau=0.2)",
     "hybrid: tau has no effect with update_mode=local (only with update_mode=shift"),
    ("hybrid(update_mode=local, stages=2)", "hybrid: stages has no effect with update_mode=local"),
    ("hybrid(update_mode=local, shifts=2)", "hybrid: shifts has no effect with update_mode=local"),
    ("hybrid(update_mode=local, min_ess=0.1)",
     "hybrid: min_ess has no effect with update_mode=local"),
    ("hybrid(update_mode=local, kernel=0.2)",
     "hybrid: kernel has no effect with update_mode=local"),
    ("hybrid(bandwidth=0.3)", "hybrid: bandwidth has no effect with update_mode=shift"),
    ("hybrid(weights=equal, tau=0.5)",
     "hybrid: tau has no effect with weights=equal (only with weights=confidence)"),
    ("hybrid(sampling=random, spread=0.4)", "hybrid: spread has no effect with sampling=random"),
    ("ukf(points=cubature, alpha=0.5)", "ukf: alpha has no effect with points=cubature"),
    ("ukf(alpha=1, alpha=2)", "ukf: parameter alpha given twice"),
    ("ukf(alpha)", "ukf: bad parameter 'alpha': expected key=value"),
    ("ukf(", "bad filter spec 'ukf('"),
]


@pytest.mark.parametrize("text, msg", BAD, ids=[b[0] for b in BAD])
def test_bad_spec_raises_one_line_naming_the_parameter(text, msg):
    with pytest.raises(SpecError) as e:
        parse_spec(text)
    s = str(e.value)
    assert "\n" not in s
    assert s.startswith(msg), s
    assert isinstance(e.value, ValueError)  # callers that catch ValueError keep working
    with pytest.raises(SpecError):
        make_filter(text)  # the compatibility wrapper validates the same way


def test_parsed_spec_holds_every_parameter_and_the_label_as_written():
    s = parse_spec("hybrid( n_cloud=20, tau=0.5 )")
    assert s.name == "hybrid" and s.label == "hybrid( n_cloud=20, tau=0.5 )"
    assert s.params["n_cloud"] == 20 and isinstance(s.params["n_cloud"], int)
    assert s.params["tau"] == 0.5 and s.params["update_mode"] == "shift"
    assert set(s.params) == set(param_table("hybrid"))
    assert s.user == {"n_cloud", "tau"}
    with pytest.raises(TypeError):
        s.params["tau"] = 0.1  # frozen
    f = build(s)
    assert isinstance(f, HybridShift) and (f.n_cloud, f.tau) == (20, 0.5)
    # an integer-valued float is accepted as an integer, and 1 as a float
    assert parse_spec("hybrid(n_cloud=20.0)").params["n_cloud"] == 20
    assert parse_spec("ukf(alpha=1)").params["alpha"] == 1.0


def test_local_mode_declares_only_its_parameters_and_builds_its_class():
    s = parse_spec("hybrid(update_mode=local, bandwidth=0.4)")
    assert set(s.params) == {"update_mode", "sampling", "weights", "gamma", "n_cloud", "spread",
                             "regen_ess", "bandwidth"}
    f = build(s)
    assert isinstance(f, HybridLocal) and f.update_mode == "local" and f.bandwidth == 0.4


def test_every_registered_class_declares_its_parameters_next_to_it():
    for name in REGISTRY:
        table = param_table(name)
        for k, (p, default) in table.items():
            assert p.allowed()  # every parameter says what it accepts
            if k != "update_mode":
                p.check(name, k, default)  # defaults are valid values


def test_sh_specs_wrap_and_split_parameters():
    f = build(parse_spec("hybrid_sh(b=0.97, n_cloud=4, adapt=RQ)"))
    assert isinstance(f, SageHusa) and (f.b, f.adapt) == (0.97, "RQ")
    assert isinstance(f.filter, HybridShift) and f.filter.n_cloud == 4
    assert f.name == "hybrid_sh"
    assert isinstance(build("ckf"), CKF) and isinstance(build("ckf"), UKF)


def test_spec_is_json_ready_and_round_trips():
    s = presets.resolve("hybrid_sh(tau=0.5)", "attitude", dim=6)
    d = json.loads(json.dumps(s.as_dict()))
    assert d["name"] == "hybrid_sh" and d["label"] == "hybrid_sh(tau=0.5)"
    assert d["preset"] == "attitude" and d["dim"] == 6
    assert d["params"]["tau"] == 0.5 and d["params"]["n_cloud"] == 16
    again = parse_spec(s.text())
    assert dict(again.params) == dict(s.params)
    assert hash(s) == hash(FilterSpec(s.name, dict(s.params), s.label, s.preset, s.user, s.dim))


def test_filter_list_refuses_duplicates_and_empty():
    specs = parse_filter_list("ekf, ukf(alpha=0.5,kappa=1), hybrid")
    assert [s.label for s in specs] == ["ekf", "ukf(alpha=0.5,kappa=1)", "hybrid"]
    with pytest.raises(SpecError, match="ekf more than once"):
        parse_filter_list("ekf,ekf")
    with pytest.raises(SpecError, match="ukf and ukf\\(alpha=1\\) more than once"):
        parse_filter_list("ukf,ukf(alpha=1)")  # same filter, same parameters
    with pytest.raises(SpecError, match="empty"):
        parse_filter_list("")
    with pytest.raises(SpecError, match="empty"):
        parse_filter_list(" , ")


# ------------------------------------------------------------------------------- presets


def test_presets_resolve_what_hybrid_means_in_each_command():
    bench = presets.resolve("hybrid", "bench", dim=1)
    att = presets.resolve("hybrid", "attitude", dim=6)
    radar = presets.resolve("hybrid", "radar", dim=4)
    assert (bench.params["update_mode"], bench.params["n_cloud"], bench.params["tau"]) == (
        "shift", 32, 0.3)
    assert (att.params["update_mode"], att.params["n_cloud"], att.params["tau"]) == (
        "shift", 16, 0.9)
    assert (radar.params["update_mode"], radar.params["n_cloud"]) == ("local", 64)
    assert "tau" not in radar.params
    assert att.params["gamma"] == pytest.approx(np.sqrt(6))  # dimension-dependent, resolved
    assert bench.params["gamma"] == pytest.approx(np.sqrt(3))
    assert isinstance(presets.build(radar), HybridLocal)
    # the _sh variant gets the same preset values
    assert presets.resolve("hybrid_sh", "radar").params["n_cloud"] == 64
    # other filters are unaffected by a hybrid preset
    assert dict(presets.resolve("ukf", "radar").params) == dict(parse_spec("ukf").params)


def test_user_parameters_win_over_presets():
    s = presets.resolve("hybrid(n_cloud=8, update_mode=shift)", "radar", dim=4)
    assert (s.params["update_mode"], s.params["n_cloud"], s.params["tau"]) == ("shift", 8, 0.3)
    s = presets.resolve("hybrid(tau=0.5)", "attitude", dim=6)
    assert (s.params["n_cloud"], s.params["tau"]) == (16, 0.5)
    # a preset value without effect in the mode the user chose is dropped, not an error
    s = presets.resolve("hybrid(update_mode=local)", "attitude", dim=6)
    assert "tau" not in s.params and s.params["n_cloud"] == 16
    # a resolved spec passed again keeps its user parameters and re-resolves the rest
    again = presets.resolve(presets.resolve("hybrid(n_cloud=8)", "attitude", dim=6), "radar", 4)
    assert (again.params["update_mode"], again.params["n_cloud"]) == ("local", 8)
    assert again.preset == "radar" and again.label == "hybrid(n_cloud=8)"
    # a user parameter that the preset's mode makes meaningless is an error, not ignored
    with pytest.raises(SpecError, match="tau has no effect with update_mode=local"):
        presets.resolve("hybrid(tau=0.5)", "radar", dim=4)


def test_bench_enkf_members_match_the_hybrid_of_the_same_run():
    n = 2
    alone = presets.resolve("enkf", "bench", dim=n)
    assert alone.params["members"] == HybridShift().members(n)  # the preset's own hybrid
    specs = presets.resolve_list("ekf,enkf,etkf(members=7),hybrid(n_cloud=4)", "bench", dim=n)
    by = {s.label: s for s in specs}
    assert by["enkf"].params["members"] == HybridShift(n_cloud=4).members(n) == 25
    assert by["etkf(members=7)"].params["members"] == 7  # written by the user: wins
    assert isinstance(presets.build(by["enkf"]), EnKF) and presets.build(by["enkf"]).members == 25
    with pytest.raises(SpecError, match="dimension"):
        presets.resolve("enkf", "bench")
    # no member matching outside bench (replay/track keep the EnKF's own default)
    assert presets.resolve("enkf", "attitude", dim=6).params["members"] == 100


def test_unknown_preset_and_filter_are_named():
    with pytest.raises(SpecError,
                       match="unknown preset 'replay'; known: bench, attitude, nav, radar"):
        presets.resolve("ekf", "replay")
    with pytest.raises(SpecError, match="unknown filter 'nope'"):
        presets.resolve("nope", "bench", dim=1)
    with pytest.raises(SpecError, match="more than once"):
        presets.resolve_list("ekf,ekf", "bench", dim=1)


def test_duplicates_are_judged_in_the_preset_not_with_core_defaults():
    # "hybrid(tau=0.3)" writes the core default, but under the attitude preset "hybrid"
    # is tau = 0.9 (and under radar update_mode=local): different filters, both allowed
    specs = presets.resolve_list("hybrid,hybrid(tau=0.3)", "attitude", dim=6)
    assert [s.params["tau"] for s in specs] == [0.9, 0.3]
    specs = presets.resolve_list("hybrid,hybrid(update_mode=shift, n_cloud=32)", "radar",
                                 dim=4)
    assert [s.params["update_mode"] for s in specs] == ["local", "shift"]
    # the same filter in the preset is still refused, as is the same label
    with pytest.raises(SpecError, match="resolve to the same filter in preset attitude"):
        presets.resolve_list("hybrid,hybrid(tau=0.9)", "attitude", dim=6)
    with pytest.raises(SpecError, match="hybrid and hybrid\\(tau=0.3\\), which resolve"):
        presets.resolve_list("hybrid,hybrid(tau=0.3)", "bench", dim=1)
    with pytest.raises(SpecError, match="empty entry"):
        presets.resolve_list("ekf,,ukf", "bench", dim=1)


@pytest.mark.parametrize("model, filters, refused_in", [
    ("attitude", "hybrid,hybrid(tau=0.9)", "attitude"),
    ("nav", "hybrid,hybrid(tau=0.9)", "nav"),
    ("auto", "hybrid,hybrid(tau=0.9)", "attitude"),  # one filter in both presets
    ("nav", "hybrid(reinflate=false),hybrid", None),  # two filters in the nav preset
    ("auto", "hybrid(reinflate=false),hybrid", None),  # judged once the model is chosen
    ("attitude", "hybrid(reinflate=false),hybrid", "attitude"),
])
def test_replay_judges_two_labels_in_its_models_preset(tmp_path, capsys, model, filters,
                                                       refused_in):
    """``uavest replay --filters`` before any work: in the preset of ``--model``; with
    ``auto`` a list that is a slip in both presets is refused at once and one that is two
    filters in the nav preset (where the hybrid re-spreads) goes on."""
    from uavest.cli import main

    missing = str(tmp_path / "none.tlog")
    assert main(["replay", missing, "--model", model, "--filters", filters]) == 2
    err = capsys.readouterr().err
    if refused_in:
        assert f"resolve to the same filter in preset {refused_in}" in err, err
    else:
        assert "same filter" not in err and "none.tlog" in err, err


def test_distinct_false_lets_two_labels_of_one_filter_through_but_not_one_label_twice():
    # benchmarks/radar_bound.py runs one filter under two labels (two random streams)
    text = "hybrid,hybrid(update_mode=local,n_cloud=64)"
    with pytest.raises(SpecError, match="resolve to the same filter in preset radar"):
        presets.resolve_list(text, "radar", dim=4)
    a, b = presets.resolve_list(text, "radar", dim=4, distinct=False)
    assert dict(a.params) == dict(b.params) and a.label != b.label
    with pytest.raises(SpecError, match="more than once"):
        presets.resolve_list("hybrid,hybrid", "radar", dim=4, distinct=False)


def test_the_navigation_preset_narrows_the_unscented_filters_sigma_points():
    # alpha 0.1: sigma points at 0.1 sqrt(n) std instead of sqrt(n) (about 4 std on the
    # navigation state); the other presets keep the core's alpha 1
    for name in ("ukf", "ukf_sh", "srukf"):
        assert presets.resolve(name, "nav", dim=15).params["alpha"] == 0.1
        assert presets.resolve(name, "attitude", dim=6).params["alpha"] == 1.0
    assert presets.resolve("ukf(alpha=1)", "nav", dim=15).params["alpha"] == 1.0
    text = presets.describe_presets()
    assert "ukf     -> ukf(alpha=0.1)" in text and "srukf   -> srukf(alpha=0.1)" in text


def test_describe_presets_says_what_hybrid_is_in_each_command():
    text = presets.describe_presets()
    lines = text.splitlines()
    assert any("attitude" in ln and "uavest replay" in ln for ln in lines)
    assert "hybrid(update_mode=shift, n_cloud=16, tau=0.9)" in text
    assert "hybrid(update_mode=shift, n_cloud=16, tau=0.9, reinflate=true)" in text
    assert any("nav" in ln and "navigation model" in ln for ln in lines)
    assert "hybrid(update_mode=local, n_cloud=64)" in text
    assert "members = (2n+1)(n_cloud+1) of the hybrid in the same run" in text


# --------------------------------------------------------------- compatibility wrappers


def test_make_filter_in_context_matches_presets_and_old_defaults():
    # the presets table reproduces the constants the callers used before it existed
    # (replay's HYBRID_ATTITUDE_DEFAULTS, the radar's HYBRID_RADAR_DEFAULTS)
    old_attitude = {"n_cloud": 16, "tau": 0.9}
    old_radar = {"update_mode": "local", "n_cloud": 64}
    for spec in ("hybrid", "hybrid(n_cloud=8)", "hybrid_sh", "ukf", "hybrid(update_mode=shift)"):
        for defaults, name in ((old_attitude, "attitude"), (old_radar, "radar")):
            old = make_filter_in_context(spec, defaults)
            new = presets.build(spec, name)
            assert old == new, (spec, name)


@pytest.mark.parametrize("spec", ["hybrid(n_cloud=4)", "hybrid(n_cloud=4, update_mode=local)",
                                  "hybrid(n_cloud=4, stages=2, shifts=2)"])
def test_split_hybrid_gives_the_numbers_of_the_flat_parameter_set(spec):
    """The strategy split kept the numbers: a seeded run equals the same run with the
    class built directly from the resolved parameters, and with the dimension-dependent
    gamma resolved by a preset (the existing numeric tests in tests/ pass unchanged)."""
    from uavest.models.benchmarks import UNGMMeasurement, UNGMTransition

    s = parse_spec(spec)
    cls = HybridLocal if s.params["update_mode"] == "local" else HybridShift
    direct = cls(**{k: v for k, v in s.params.items() if k != "update_mode"})
    tr, me = UNGMTransition(), UNGMMeasurement()
    resolved = presets.build(presets.resolve(spec, "bench", dim=1))  # gamma resolved to sqrt(3)
    assert resolved.gamma == pytest.approx(np.sqrt(3)) and direct.gamma is None
    out = []
    for f in (build(s), direct, resolved):
        rng = np.random.default_rng(0)
        E = f.init(Gaussian.of(0.0, 1.0), tr.space, rng)
        for k in range(1, 21):
            E = f.predict(E, tr, k, 1.0, None, rng)
            E, _ = f.update(E, np.array([0.5 * np.sin(k)]), me, rng)
        out.append(f.estimate(E))
    for o in out[1:]:
        assert np.array_equal(out[0].x, o.x) and np.array_equal(out[0].P, o.P)


# ---------------------------------------------------------------- resolved once, by the CLI


def test_the_cli_resolves_filters_once_for_the_commands_state():
    from uavest.cli import _check_filters, build_parser
    from uavest.core.spec import FilterSpec
    from uavest.engine.build import build_filters

    def specs(*argv):
        args = build_parser().parse_args(list(argv))
        _check_filters(args)
        return args.filter_specs

    att = specs("replay", "some.tlog", "--filters", "hybrid,ekf")
    assert all(isinstance(s, FilterSpec) and (s.preset, s.dim) == ("attitude", 6) for s in att)
    assert att[0].params["n_cloud"] == 16  # the attitude preset's hybrid
    again = presets.resolve_list(att, "attitude", dim=6)  # what the job does: a no-op
    assert all(a is b for a, b in zip(again, att, strict=True))
    (radar,) = specs("bench", "radar_crossing", "--filters", "hybrid")
    assert (radar.preset, radar.dim, radar.params["update_mode"]) == ("radar", 4, "local")
    bench = specs("bench", "ungm", "--filters", "enkf,hybrid(n_cloud=4)")
    assert [(s.preset, s.dim) for s in bench] == [("bench", 1)] * 2
    assert bench[0].params["members"] == 3 * 5  # the listed hybrid's M = (2n+1)(N+1)
    assert specs("bench", "no_such_scenario", "--filters", "ekf") == ["ekf"]  # reported later
    with pytest.raises(SpecError):
        specs("bench", "ungm", "--filters", "hybrid(bogus=1)")
    assert [type(f).__name__ for _, f in build_filters(bench)] == ["EnKF", "HybridShift"]
    with pytest.raises(TypeError, match="resolved FilterSpecs"):
        build_filters(["ekf"])  # the engine does not resolve spec text
