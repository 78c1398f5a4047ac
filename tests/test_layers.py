"""The layering: the lower modules (protocols, detectors, correctors, estimators, the simulator,
I/O ...) never import the composition layer (:mod:`fusionkit.pipeline`), so no import cycle
``protocols -> pipeline -> detectors -> pipeline`` can come back. Checked in a fresh interpreter,
where ``sys.modules`` shows what an import really pulled in."""

from __future__ import annotations

import json
import subprocess
import sys

#: packages and modules below the composition (every module in a package counts)
LOWER = ["fusionkit._kernels", "fusionkit._numba", "fusionkit.config", "fusionkit.conventions", "fusionkit.errors",
         "fusionkit.gnss_rows", "fusionkit.protocols", "fusionkit.registry", "fusionkit.rotations",
         "fusionkit.types", "fusionkit.validation", "fusionkit.detectors", "fusionkit.correctors",
         "fusionkit.estimators", "fusionkit.navigation", "fusionkit.sim", "fusionkit.io"]

_PROBE = r"""
import importlib, importlib.machinery, json, pkgutil, sys

# Each module is imported afresh many times below; its compiled code is kept from the first time
# (where bytecode is not written, PYTHONDONTWRITEBYTECODE, each import compiled the source again:
# half of this probe's CPU). The module's code still runs at every import, which is what is checked.
_codes = {}
_get_code = importlib.machinery.SourceFileLoader.get_code


def get_code(self, fullname):
    if self.path not in _codes:
        _codes[self.path] = _get_code(self, fullname)
    return _codes[self.path]


importlib.machinery.SourceFileLoader.get_code = get_code

def clear():
    for k in [k for k in sys.modules if k == "fusionkit" or k.startswith("fusionkit.")]:
        del sys.modules[k]

names = []
for name in sys.argv[1:]:
    m = importlib.import_module(name)
    names.append(name)
    if hasattr(m, "__path__"):
        names += [i.name for i in pkgutil.walk_packages(m.__path__, name + ".")]
    clear()
pulled = {}
for name in names:
    importlib.import_module(name)
    pulled[name] = "fusionkit.pipeline" in sys.modules
    clear()

# running detectors on their own (Detector.run) must not pull the pipeline in either
import fusionkit as fk
from fusionkit import sim
rec = sim.simulate([sim.Rest(2.0)], rate=100.0)
fk.make("rest").run(rec)
fk.make("gnss-gap").run(rec)
pulled["Detector.run"] = "fusionkit.pipeline" in sys.modules
print(json.dumps(pulled))
"""


def test_lower_layers_do_not_import_the_pipeline():
    out = subprocess.run([sys.executable, "-c", _PROBE, *LOWER], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    pulled = json.loads(out.stdout.strip().splitlines()[-1])
    assert "fusionkit.detectors.gnss_gap" in pulled and "fusionkit.protocols" in pulled
    assert len(pulled) > 20
    offenders = sorted(k for k, v in pulled.items() if v)
    assert offenders == [], f"these import fusionkit.pipeline: {offenders}"


def test_public_names_still_importable_where_they_were():
    from fusionkit.detectors import gnss_gap
    from fusionkit.detectors._run import run_detector
    from fusionkit.gnss_rows import NO_GNSS, gnss_per_sample, gnss_sample_rows
    from fusionkit.pipeline import run_detector as from_pipeline

    assert from_pipeline is run_detector
    assert gnss_gap.NO_GNSS is NO_GNSS
    assert gnss_gap.gnss_sample_rows is gnss_sample_rows
    assert gnss_gap.gnss_per_sample is gnss_per_sample
