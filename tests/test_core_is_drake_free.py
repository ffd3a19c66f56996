"""The core package never imports pydrake: fitting, clustering and diagnosis run on logs alone."""

import pkgutil
import subprocess
import sys
from pathlib import Path

import pcvfe_drake

CORE_ROOT = Path(pcvfe_drake.__file__).parent
ADAPTER_PACKAGES = ("pcvfe_drake.systems", "pcvfe_drake.diagrams", "pcvfe_drake.textures")


def core_modules() -> list[str]:
    names = []
    for info in pkgutil.walk_packages([str(CORE_ROOT)], prefix="pcvfe_drake."):
        if not info.name.startswith(ADAPTER_PACKAGES):
            names.append(info.name)
    return sorted(names)


def test_every_core_module_imports_without_pydrake():
    modules = core_modules()
    # Among them the modules the command line loads before it builds a diagram (the run folder,
    # the scenario, summary and figures, the simulate command): one interpreter checks them all.
    assert "pcvfe_drake.vehicle.single_track" in modules and "pcvfe_drake.models.model" in modules
    assert {
        "pcvfe_drake.runs.run_folder",
        "pcvfe_drake.runs.scenario",
        "pcvfe_drake.runs.summary",
        "pcvfe_drake.runs.figures",
        "pcvfe_drake.runs.runlog",
        "pcvfe_drake.commands.simulate",
    } <= set(modules)
    code = (
        "import importlib, sys\n"
        f"for name in {modules!r}:\n"
        "    importlib.import_module(name)\n"
        "import pcvfe_drake.cli\n"
        "pcvfe_drake.cli.build_parser()\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0] == 'pydrake'))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout
