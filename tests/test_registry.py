"""Entry-point discovery, look-up errors, broken and duplicate plugins, the example package."""

import re
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import fusionkit as fk
from fusionkit.errors import PluginError, PluginWarning
from fusionkit.registry import Registry

REPO = Path(__file__).resolve().parents[1]


def fake_distribution(root: Path, name: str, entry_points: str, module: str | None = None, code: str = "") -> None:
    """A minimal installed distribution (a dist-info folder) on ``root``."""
    info = root / f"{name.replace('-', '_')}-0.1.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(textwrap.dedent(entry_points))
    if module:
        (root / f"{module}.py").write_text(textwrap.dedent(code))


def fake_vqf_duplicate(root: Path) -> None:
    """A third-party filter named like the built-in ``vqf``."""
    fake_distribution(root, "fake-dup", """
        [fusionkit.filters]
        vqf = fake_dup_mod:Other
        """, "fake_dup_mod", "Other = None\n")


def fake_exiting_plugin(root: Path, code: int) -> None:
    """A detector whose module calls ``sys.exit(code)`` on import."""
    fake_distribution(root, "fake-exit", """
        [fusionkit.detectors]
        exiter = fake_exit_mod:D
        """, "fake_exit_mod", f"import sys\nsys.exit({code})\n")


@pytest.fixture
def on_path(tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(tmp_path))
    return tmp_path


def test_builtins_are_registered_through_entry_points():
    av = fk.available()
    assert {"poisson", "pipeline"} <= set(av["filters"])
    assert {"poisson-quat", "poisson-dcm"} <= set(av["estimators"])
    assert "motion" in av["detectors"]
    assert fk.available("detector") == av["detectors"]
    assert ("filter", "poisson", "fusionkit") in fk.default_registry().info()


def test_make_resolves_filters_first_and_other_kinds_by_name():
    assert fk.make("poisson").kind == "filter"
    assert fk.make("motion").kind == "detector"  # unique name in another kind
    assert fk.make("poisson-dcm", kind="estimators").kind == "estimator"
    with pytest.raises(PluginError, match="kind must be one of"):
        fk.make("poisson", kind="smoother")


def test_unknown_names_list_close_matches():
    with pytest.raises(PluginError, match="did you mean 'poisson'"):
        fk.make("poison")
    with pytest.raises(PluginError, match="unknown detector plugin 'moton'.*'motion'"):
        fk.make("moton", kind="detector")


def test_a_plugin_in_the_wrong_list_is_named_with_its_kind():
    """"rest" under correctors said "unknown corrector plugin 'rest'; did you mean 'rest-bias'" without
    saying that 'rest' is a registered detector (likewise a corrector given as the estimator)."""
    base = {"estimator": "poisson-quat", "alignment": {"mode": "fixed"}}
    for cfg, message in (
            ({**base, "correctors": ["rest"]}, r"unknown corrector plugin 'rest' \('rest' is a detector: in a "
                                               r"composition list it under detectors\); did you mean 'rest-bias'"),
            ({**base, "estimator": {"name": "dcm-vertical"}},
             r"unknown estimator plugin 'dcm-vertical' \('dcm-vertical' is a corrector: in a composition list it "
             r"under correctors"),
            ({**base, "detectors": ["calibration"]}, r"'calibration' is a sensor model: .* list it under models"),
            ({**base, "estimator": "poisson"}, r"'poisson' is a filter, not a part of a composition: build it with "
                                               r"make\('poisson'\)")):
        with pytest.raises(PluginError, match=message):
            fk.compose(cfg)
    with pytest.raises(PluginError, match=r"unknown detector plugin 'moton'; did you mean"):  # no kind has it
        fk.make("moton", kind="detector")


def test_a_name_or_kind_that_is_not_a_string_is_named():
    """Before: difflib's TypeError from the close-match hint, and AttributeError ``endswith`` for the
    parameters passed as a dict where the kind goes."""
    for name in (None, 3, ["recommended"]):
        with pytest.raises(PluginError, match="a plugin name is a string"):
            fk.make(name)
    with pytest.raises(PluginError, match="kind must be one of .* parameters are keywords"):
        fk.make("recommended", {"tau_acc": 1.0})


def test_a_boolean_for_a_number_is_refused():
    """``tau_acc=True`` ran with 1 s (pydantic takes True as 1); a boolean stays valid for a boolean
    field."""
    for params in ({"tau_acc": True}, {"gyr_range": False}, {"mag_delay": True}):
        with pytest.raises(fk.ConfigError, match="expected a number, got a boolean"):
            fk.make("recommended", **params)
    assert fk.make("recommended", use_mag=False).config.use_mag is False


@pytest.mark.parametrize("name, params, match", [
    ("recommended", {"bias_sigma_rest": True}, "expected a number, got a boolean"),  # Annotated in a union
    ("vqf-basic", {"tau_acc": np.True_}, "expected a number, got a boolean"),
    ("ins-gnss", {"lever_arm": (True, 0, 0)}, r"expected numbers, got a boolean in \(True, 0, 0\)"),
    ("ins-gnss", {"gnss_vel_std": [0.1, False]}, "expected numbers, got a boolean"),
])
def test_a_boolean_for_a_number_is_refused_where_it_hid(name, params, match):
    """Booleans the first check let through, each run as 1 or 0: in an ``Annotated`` number within
    a union (``bias_sigma_rest=True`` ran with 1.0), numpy's ``np.True_``, and inside a tuple of
    numbers (``lever_arm=(True, 0, 0)`` ran with 1 m)."""
    with pytest.raises(fk.ConfigError, match=match):
        fk.make(name, **params)
    assert fk.make("ins-gnss", lever_arm=(1, 0, 0)).config.lever_arm == (1.0, 0.0, 0.0)


def test_a_streamed_interval_is_bounded():
    """``update(dt=100)`` (an interval in ms?) ended in a division by zero in recommended's kernel;
    a boolean dt was taken as 1 s."""
    for name in ("recommended", "ekf", "vqf"):
        f = fk.make(name)
        with pytest.raises(fk.InputError, match="dt must be at most 1 s"):
            f.update([0.1, 0.0, 0.0], [0.0, 0.0, 9.81], dt=100.0)
        with pytest.raises(fk.InputError, match="dt must be one finite number"):
            f.update([0.1, 0.0, 0.0], [0.0, 0.0, 9.81], dt=True)
    # the check's own switch says what it does (it was ``first``, which ins-gnss passed for every interval)
    from fusionkit.validation import check_dt
    assert check_dt(5.0, bounded=False) == 5.0
    with pytest.raises(fk.InputError, match="dt must be at most 1 s"):
        check_dt(5.0, bounded=True)


def test_streamed_text_is_refused():
    """Text that parses as a number (``dt="0.01"``, a timestamp ``t="5.0"``) is refused as text is in
    a Recording, naming the argument."""
    with pytest.raises(fk.InputError, match=r"dt must be a finite number > 0, got '0.01' \(text"):
        fk.make("recommended").update([0.1, 0.0, 0.0], [0.0, 0.0, 9.81], dt="0.01")
    with pytest.raises(fk.InputError, match="acc must be numbers .*not text"):
        fk.make("recommended").update([0.1, 0.0, 0.0], ["0", "0", "9.81"], dt=0.01)
    with pytest.raises(fk.InputError, match=r"t must be one finite number \(a timestamp in s\), got '5.0'"):
        fk.make("ins-gnss").update([0.1, 0.0, 0.0], [0.0, 0.0, 9.81], dt=0.01, t="5.0")
    # a GNSS epoch holding text: the readable pipeline step and ins-gnss once parsed it silently
    f = fk.make("gst-gnss")
    f.update_backend = "reference"
    with pytest.raises(fk.InputError, match="gnss must be numbers .*not text such as"):
        f.update([0.1, 0.0, 0.0], [0.0, 0.0, 9.81], dt=0.01, gnss=(0.0, "1.0", 0.0, 0.0, 0.0, 0.0))
    # a GNSS row's validity fields are booleans by meaning: taken, also from an object row
    f.update([0.1, 0.0, 0.0], [0.0, 0.0, 9.81], dt=0.01,
             gnss=np.array([1.0, 0.5, True, 0.0, np.True_, 0.0], dtype=object))
    with pytest.raises(fk.InputError, match="gnss must be numbers .*not text such as"):
        fk.make("ins-gnss").update([0.1, 0.0, 0.0], [0.0, 0.0, 9.81], dt=0.01,
                                   gnss=(0.0, "1.0", 0.0, 0.0, 0.0, 0.0, 0.0))


def test_a_later_long_interval_is_a_gap_not_an_error():
    """Only the stream's first interval (its nominal rate) is bounded: a pause of 5 s later in a stream
    is a timestamp gap, held across and flagged as a Recording's is (the bound once refused it)."""
    for name in ("recommended", "gradient-descent", "vqf", "ekf"):  # a pipeline, a preset, a peer, a step filter
        f = fk.make(name)
        # the gap is told before either step runs: the readable one here (the compiled one-sample steps
        # would cost ~40 s of compiling for what the check does not depend on)
        f.update_backend = "reference"
        for _ in range(20):
            f.update([0.0, 0.0, 0.0], [0.0, 0.0, 9.81], dt=0.01)
        q = f.update([0.0, 0.0, 0.0], [0.0, 0.0, 9.81], dt=5.0)
        assert np.isfinite(q).all(), name
        assert f.last_flags & fk.Flag.GAP, name
    # a step filter's stream after set_state has no nominal interval yet: its first dt is bounded
    # (before: taken unchecked, dt=100 set a gap threshold no later gap reached)
    f, g = fk.make("ekf"), fk.make("ekf")
    f.update_backend = g.update_backend = "reference"
    for _ in range(5):
        f.update([0.0, 0.0, 0.0], [0.0, 0.0, 9.81], dt=0.01)
    g.set_state(f.state)
    with pytest.raises(fk.InputError, match="dt must be at most 1 s"):
        g.update([0.0, 0.0, 0.0], [0.0, 0.0, 9.81], dt=100.0)
    # set_state on a filter that streamed before: the taken state's next dt is bounded as a first one
    f.set_state(g.state if g.state is not None else f.state)
    with pytest.raises(fk.InputError, match="dt must be at most 1 s"):
        f.update([0.0, 0.0, 0.0], [0.0, 0.0, 9.81], dt=100.0)
    # ins-gnss has no gap handling: a long interval later in its stream is refused, not integrated
    h = fk.make("ins-gnss")
    h.update([0.0, 0.0, 0.0], [0.0, 0.0, 9.81], dt=0.01)
    with pytest.raises(fk.InputError, match="dt must be at most 1 s"):
        h.update([0.0, 0.0, 0.0], [0.0, 0.0, 9.81], dt=5.0)


def test_describe_lists_parameters_with_units_and_defaults():
    info = fk.describe("motion")
    rows = {p["name"]: p for p in info.parameters}
    assert rows["angle_threshold"]["default"] == 0.01 and rows["angle_threshold"]["unit"] == "rad"
    assert rows["gyr_norm_sigma"]["default"] == 20.0
    assert "000" in info.source
    text = str(info)
    assert "velocity_threshold = 0.02 [m/s] (> 0)" in text
    assert info.composition is None  # not a preset


def test_describe_shows_a_presets_composition():
    info = fk.describe("channel-dcm")
    c = info.composition
    assert c["estimator"] == {"name": "poisson-dcm", "params": {"orthonormalize": False}}
    assert [x["name"] for x in c["correctors"]] == ["dcm-vertical", "dcm-north"]
    assert c["correctors"][0]["params"] == {"method": "columns", "k_acc": 0.3, "orthonormalize": False}
    assert "correctors: dcm-vertical(method='columns'" in str(info)
    assert fk.describe("pipeline").composition is None  # composed by its user's config


def test_broken_plugin_is_reported_with_its_distribution_and_others_still_work(on_path):
    fake_distribution(on_path, "fake-broken", """
        [fusionkit.filters]
        broken = fake_broken_mod:Nope
        """, "fake_broken_mod", "raise ImportError('missing dependency xyz')\n")
    reg = Registry()
    assert "broken" in reg.names("filter")
    with pytest.raises(PluginError, match="'broken' from distribution 'fake-broken'.*missing dependency xyz"):
        reg.make("broken")
    assert reg.make("poisson").name == "poisson"
    errors = reg.check_all()
    assert list(errors) == ["filter:broken"]


def test_non_plugin_object_is_rejected(on_path):
    fake_distribution(on_path, "fake-notaplugin", """
        [fusionkit.detectors]
        notaplugin = fake_np_mod:thing
        """, "fake_np_mod", "thing = 42\n")
    with pytest.raises(PluginError, match="not a fusionkit detector class"):
        Registry().get("notaplugin", "detector")


def test_a_third_party_plugin_named_like_a_builtin_is_reported_and_the_builtin_wins(on_path):
    fake_vqf_duplicate(on_path)
    reg = Registry()
    with pytest.warns(PluginWarning, match=r"filter 'vqf': fake_dup_mod:Other from fake-dup is ignored"):
        names = reg.names("filter")
    assert "vqf" in names and reg.make("poisson").name == "poisson"
    from fusionkit.peers import VqfFilter

    assert reg.get("vqf") is VqfFilter and ("filter", "vqf", "fusionkit") in reg.info()
    assert len(reg.duplicates) == 1 and "fusionkit.peers.vqf:VqfFilter" in reg.duplicates[0]
    assert reg.check_all() == {}


def test_two_third_party_plugins_with_one_name_fail_only_when_asked_for(on_path):
    for dist, mod in (("fake-one", "fake_one_mod"), ("fake-two", "fake_two_mod")):
        fake_distribution(on_path, dist, """
            [fusionkit.filters]
            same-name = %s:F
            """ % mod, mod, "F = None\n")
    reg = Registry()
    assert "same-name" in reg.names("filter") and reg.make("poisson").name == "poisson"
    with pytest.raises(PluginError, match=r"duplicate filter name 'same-name'") as info:
        reg.make("same-name")
    assert "fake_one_mod:F from fake-one" in str(info.value) and "fake_two_mod:F from fake-two" in str(info.value)
    assert list(reg.check_all()) == ["filter:same-name"]


def test_a_plugin_calling_sys_exit_on_import_is_a_broken_plugin(on_path):
    fake_exiting_plugin(on_path, 3)
    reg = Registry()
    with pytest.raises(PluginError, match=r"'exiter' from distribution 'fake-exit'.*SystemExit: 3"):
        reg.make("exiter", kind="detector")
    assert list(reg.check_all()) == ["detector:exiter"] and reg.make("motion").name == "motion"


def test_cli_list_reports_a_duplicate_and_a_plugin_that_exits(on_path, capsys):
    from fusionkit.cli import main

    fake_vqf_duplicate(on_path)
    fake_exiting_plugin(on_path, 0)
    fk.default_registry().refresh()
    try:
        code = main(["list"])
    finally:
        fk.default_registry().refresh()
    cap = capsys.readouterr()
    out = cap.out
    assert code == 1
    # the duplicate's PluginWarning: on stderr, one line, as the command line prints a warning
    assert re.search(r"^fusionkit: warning: duplicate plugin name: filter 'vqf': fake_dup_mod:Other from fake-dup is ignored.* "
                     r"\(PluginWarning\)$", cap.err, re.M), cap.err
    assert "DUPLICATE: filter 'vqf': fake_dup_mod:Other from fake-dup is ignored" in out
    assert re.search(r"detector\s+exiter\s+\[fake-exit\]\s+BROKEN: .*SystemExit: 0", out)
    assert re.search(r"filter\s+poisson\s+\[fusionkit\]", out)


def test_registering_a_class_an_entry_point_also_names_is_one_plugin(on_path):
    """Registering in code the class an installed entry point names (``module:class``, or an alias
    that loads to it) made the name a "duplicate corrector name" and unusable, though it is the
    same class; a different class under the name stays an error."""
    import importlib

    fake_distribution(on_path, "fake-same", """
        [fusionkit.correctors]
        same-cor = fake_same_mod:SameCor
        alias-cor = fake_same_mod:Alias
        """, "fake_same_mod", """
        from fusionkit.protocols import Corrector

        class SameCor(Corrector):
            name = "same-cor"
            mode = "rate"

            def correct(self, estimator, est_state, state, sample, flags):  # (a corrector implements it)
                return None

        class Alias(SameCor):
            name = "alias-cor"

        class Other(SameCor):
            name = "same-cor"
        """)
    mod = importlib.import_module("fake_same_mod")
    mod.Alias.__module__ = "elsewhere"  # named by another module:class than the entry point's: found by loading it
    reg = Registry()
    reg.register(mod.SameCor)
    reg.register(mod.Alias)
    assert reg.get("same-cor", "corrector") is mod.SameCor and reg.get("alias-cor", "corrector") is mod.Alias
    assert ("corrector", "same-cor", "fake-same") in reg.info() and reg.check_all() == {} and not reg.duplicates
    reg.register(mod.Other)  # another class under the same name: still refused, naming both
    with pytest.raises(PluginError, match=r"duplicate corrector name 'same-cor': fake_same_mod:SameCor from fake-same "
                                          r"and fake_same_mod:Other from <registered in code>"):
        reg.get("same-cor", "corrector")


def test_register_in_code():
    from fusionkit.estimators.poisson import PoissonQuat

    class Mine(PoissonQuat):
        name = "mine"

    reg = Registry(use_entry_points=False)
    reg.register(Mine)
    assert reg.names() == ["mine"] and reg.get("mine") is Mine
    with pytest.raises(PluginError, match="not a plugin class"):
        reg.register(int)


@pytest.fixture(scope="module")
def example_plugin_installed(tmp_path_factory):
    """pip-install examples/plugin into a temporary target folder and put it on sys.path."""
    target = tmp_path_factory.mktemp("site")
    cmd = [sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation",
           "--target", str(target), str(REPO / "examples" / "plugin")]
    out = subprocess.run(cmd, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    sys.path.insert(0, str(target))
    fk.default_registry().refresh()
    yield target
    sys.path.remove(str(target))
    for mod in [m for m in sys.modules if m.startswith("fusionkit_example_plugin")]:
        del sys.modules[mod]
    fk.default_registry().refresh()


def test_example_plugin_package_installs_and_passes_its_tests(example_plugin_installed):
    info = {(k, n): d for k, n, d in fk.default_registry().info()}
    assert info[("corrector", "example-tilt")] == "fusionkit-example-plugin"
    assert info[("filter", "example-complementary")] == "fusionkit-example-plugin"
    from fusionkit.testing import check_plugin

    check_plugin("example-tilt")
    check_plugin("example-complementary")
    # the plugin's own test file, run as its author would, with pytest alone (the suite's own
    # plugins, xdist, hypothesis, benchmark, not loaded: 1.9 -> 1.1 s of CPU; the file uses none)
    env_path = f"{example_plugin_installed}:{REPO}"
    out = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                          str(REPO / "examples" / "plugin" / "tests")], capture_output=True, text=True,
                         env={**__import__("os").environ, "PYTHONPATH": env_path, "PYTEST_DISABLE_PLUGIN_AUTOLOAD": "1"})
    assert out.returncode == 0, out.stdout + out.stderr
    assert "2 passed" in out.stdout


def test_example_corrector_reduces_drift(example_plugin_installed):
    """The third-party corrector really corrects: after a gyro bias change (after the alignment
    estimated the bias) the tilt loop holds the inclination where gyro integration alone drifts."""
    from fusionkit import sim
    from fusionkit.benchmarking.metrics import rms_errors

    rec = sim.simulate([sim.Rest(2), sim.Rotate((0, 0, 1), 2.0, 10.0), sim.Rest(20)], rate=100.0,
                       noise=sim.Noise(gyr_noise=0.002, acc_noise=0.02), seed=4)
    bias_step = np.where(rec.time[:, None] > 2.0, [0.01, -0.01, 0.0], 0.0)
    drifting = fk.Recording(gyr=rec.gyr + bias_step, acc=rec.acc, rate=100.0, truth=rec.truth,
                            movement=rec.movement)
    comp = rms_errors(fk.make("example-complementary").run(drifting), drifting)["inclination"]
    gyro = rms_errors(fk.make("poisson", alignment="fixed", alignment_duration=1.0).run(drifting), drifting)["inclination"]
    # a proportional loop leaves bias / k_p = 0.014 rad (0.8 deg); gyro integration drifts without bound
    assert comp < np.degrees(0.0142) and gyro > 4 * comp


def test_recommended_with_a_third_party_part(example_plugin_installed, tmp_path):
    """docs/configuration.md: ``recommended``'s composition with its inclination factor replaced by
    the example package's tilt loop (a rate corrector: it goes before the factor correctors) runs
    from a TOML file; the heading factor is still heading-only on top of it."""
    import dataclasses

    from fusionkit import sim
    from fusionkit.config import to_toml
    from fusionkit.rotations import quat_to_matrix

    cfg = fk.describe("recommended").config()
    names = [c["name"] for c in cfg["correctors"]]
    assert names == ["rest-bias-lowpass", "inertial-tilt", "mag-heading"]
    cfg["correctors"][1] = {"name": "example-tilt", "params": {"k_p": 2.0}}
    path = tmp_path / "mine.toml"
    path.write_text(to_toml(cfg))
    rec = sim.simulate([sim.Rest(2.0), sim.Rotate((1, 0, 0), 0.8, 1.0), sim.Rotate((0, 0, 1), 1.5, 1.0)], rate=100.0,
                       noise=sim.Noise(gyr_noise=0.003, acc_noise=0.03, mag_noise=0.3), seed=2, gnss_rate=None)
    mine = fk.compose(path)
    res = mine.run(rec)
    assert [c.name for c in mine.correctors] == ["rest-bias-lowpass", "example-tilt", "mag-heading"]
    assert res.diagnostics["backend"] == "reference"  # the example's corrector has no kernel
    up = lambda q: np.einsum("nji,j->ni", quat_to_matrix(q), [0, 0, 1.0])  # noqa: E731
    tilt = np.degrees(np.arccos(np.clip(np.sum(up(res.quat) * up(rec.truth), axis=1), -1, 1)))
    assert tilt[-100:].mean() < 2.0
    assert np.abs(res.quat - fk.make("recommended").run(rec).quat).max() > 1e-3  # a different inclination
    no_mag = mine.run(dataclasses.replace(rec, mag=None))
    np.testing.assert_allclose(up(res.quat), up(no_mag.quat), atol=1e-12)


def test_every_registered_plugin_is_in_the_readmes_table():
    """The README's "What is in it" table names every plugin fusionkit registers (the `lever-arm` model was
    missing from it)."""
    import re

    from fusionkit.registry import default_registry

    text = (REPO / "README.md").read_text()
    table = text[text.index("## What is in it"):]
    table = table[:table.index("\n\n", table.index("|"))]
    listed = {n for row in table.splitlines() if row.startswith("| `")
              for n in re.findall(r"`([^`]+)`", row.split("|")[1])}
    ours = {e.name for k, es in default_registry()._discover().items() for e in es.values()
            if e.distribution in (None, "fusionkit")}
    assert ours - listed == set(), ours - listed
