"""Regenerate the Python LCM types in ``pcvfe_drake/lcmtypes/`` from the ``.lcm`` files here.

The generated modules are committed (a clean clone works without running this); a test checks
that they are what ``lcm-gen`` (from the pinned ``lcm`` package) makes of these files. Run:

    .venv/bin/python lcmtypes/generate.py
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
TARGET = HERE.parent / "pcvfe_drake" / "lcmtypes"


def lcm_gen_executable() -> str:
    """Path of ``lcm-gen`` next to this Python (the ``lcm`` package's), or on PATH."""
    local = Path(sys.executable).parent / "lcm-gen"
    if local.is_file():
        return str(local)
    found = shutil.which("lcm-gen")
    if found is None:
        raise FileNotFoundError("lcm-gen not found: pip install the pinned `lcm` package")
    return found


def generate(out_root: Path) -> Path:
    """Run ``lcm-gen --python`` on every ``.lcm`` file here into ``out_root``; returns the
    generated ``pcvfe_drake/lcmtypes`` folder inside it."""
    sources = sorted(str(p) for p in HERE.glob("*.lcm"))
    subprocess.run(
        [lcm_gen_executable(), "--python", "--ppath", str(out_root), *sources], check=True
    )
    return out_root / "pcvfe_drake" / "lcmtypes"


def main() -> int:
    with tempfile.TemporaryDirectory() as tmp:
        generated = generate(Path(tmp))
        TARGET.mkdir(exist_ok=True)
        for path in generated.glob("*.py"):
            shutil.copyfile(path, TARGET / path.name)
            print(f"wrote {TARGET / path.name}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
