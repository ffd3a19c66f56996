"""The cases of ``validation/bad_inputs_sweep.py``: bad and unusual inputs of every ``pcvfe``
command a new user meets, by category (scenario files, ``--with`` layering, course YAML, vehicle
YAML (+ fit), replay of damaged run folders, ``evaluate --report`` on damaged folders,
``import-bag``, ``features``, ``diagnose`` / ``fit``), with the fixtures they damage.

Each case is a different input a user could produce: wrong types, ranges, NaN and infinities,
missing, empty, truncated or zeroed files, wrong units, unknown keys, huge sizes, read-only
folders, odd paths. What each should end in (a named error, or the documented degraded
behaviour) is its ``expect``; what the sweep makes of the outcome is in the sweep's docstring.
"""

from __future__ import annotations

import io
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

ROOT = Path(__file__).resolve().parents[1]
PCVFE = [sys.executable, "-m", "pcvfe_drake.cli"]


# ----------------------------------------------------------------------------- fixtures
def make_run(work: Path) -> Path:
    run = work / "fixture_run"
    cmd = [*PCVFE, "simulate", "--duration", "2.5", "--no-meshcat", "--no-progress", "--out"]
    subprocess.run([*cmd, str(run)], check=True, capture_output=True, cwd=work)
    return run


def make_results(work: Path) -> Path:
    from pcvfe_drake.evaluation.store import ResultStore

    store = ResultStore(work / "fixture_results")
    store.start({"name": "tiny", "sources": [{"name": "pcvfe"}, {"name": "fixed"}]}, {"x": 1})
    for source in ("pcvfe", "fixed"):
        for seed in (0, 1):
            t = np.arange(50) * 0.1
            buffer = io.BytesIO()
            pd.DataFrame({"t": t, "mu_hat": 0.5 + 0 * t}).to_parquet(buffer)
            spec = {
                "run_id": f"paper_sim__{source}__s00{seed}",
                "experiment": "tiny",
                "scenario_name": "paper_sim",
                "source": source,
                "seed": seed,
                "spec_hash": "h",
                "scenario": {"name": "paper_sim", "course": "slalom"},
            }
            summary = {"sim_time_s": 5.0, "wall_time_s": 1.0, "mean_speed_mps": 5.0 + seed}
            result = {"status": "done", "summary": summary, "drive_log_parquet": buffer.getvalue()}
            store.record(spec, result)
    return store.root


def make_bag(work: Path) -> Path:
    sys.path.insert(0, str(ROOT / "tests"))
    from bag_writer import write_bag
    from rosbags.rosbag2 import StoragePlugin

    bag = work / "fixture_bag"
    write_bag(bag, StoragePlugin.MCAP)
    return bag


def make_log(work: Path) -> Path:
    from pcvfe_drake.models.synthetic_drive import drive_frame, s_curve_drive
    from pcvfe_drake.vehicle.params import ford_escort

    path = work / "fixture_log.csv"
    t, states, inputs = s_curve_drive(ford_escort(), [0.8], duration_s=10.0)
    drive_frame(t, states[0], inputs[0]).to_csv(path, index=False)
    return path


# ----------------------------------------------------------------------------- cases
class Case:
    """One CLI call: ``args`` (strings, ``{name}`` filled from the fixtures), files to write
    first (``{relative path: text or bytes}``), a damage to a copy of a fixture, the expected
    outcome; ``says``: words the error line must hold (the file, the dotted field; ``{name}``
    filled in too); ``prepare(tmp)``: run after the files are written (a read-only folder);
    ``check(tmp, stdout, stderr)``: after an expected outcome, ``None`` or
    ``(outcome, why)`` for a result that is silently wrong (``wrong``) or lost data (``lost``)."""

    def __init__(
        self,
        category,
        name,
        args,
        expect="error",
        files=None,
        damage=None,
        says=(),
        check=None,
        prepare=None,
    ):
        self.category, self.name, self.args = category, name, args
        self.expect, self.files, self.damage = expect, files or {}, damage
        self.says, self.check, self.prepare = tuple(says), check, prepare


def _zero(path: Path, frac: float, size: int) -> None:
    data = bytearray(path.read_bytes())
    start = int(len(data) * frac)
    data[start : start + size] = bytes(size)
    path.write_bytes(bytes(data))


def _vehicle(**changes) -> str:
    from pcvfe_drake.vehicle.params import roboracer

    data = roboracer().to_dict()
    data.pop("name")
    data.update(changes)
    return yaml.safe_dump(data)


def cases() -> list[Case]:
    out: list[Case] = []
    sim = ["simulate", "--no-meshcat", "--no-progress", "--out", "{tmp}/run"]

    def scenario(name, text, expect="error"):
        out.append(
            Case(
                "scenario files", name, [sim[0], "{tmp}/s.yaml", *sim[1:]], expect, {"s.yaml": text}
            )
        )

    scenario("not YAML", "rates: [: :\n")
    scenario("a list", "- 1\n")
    scenario("unknown field", "ratez: {}\n")
    scenario("wrong type", "seed: many\n")
    scenario("NaN duration", "duration_s: .nan\n")
    scenario("negative laps", "laps: -1\n")
    scenario("derived field", "nmpc: {dt_s: 0.1}\n")
    scenario("log period 1e-6", "rates: {log_period_s: 1.0e-6}\n")
    scenario("fitter sampling 1e-5", "rates: {fitter_sample_period_s: 1.0e-5}\n")
    scenario("camera 1e-4", "rates: {camera_period_s: 1.0e-4}\n")
    scenario("max_duration 1e9", "max_duration_s: 1.0e9\n")
    scenario("integrator step 1e-7", "simulator: {max_step_size: 1.0e-7}\n")
    scenario("horizon 100000", "nmpc: {horizon: 100000}\n")
    scenario("negative max speed", "nmpc: {max_speed_mps: -3.0}\n")
    scenario("unknown layout", "terrain_layout: moon\n")
    scenario("unknown truth model", "truth_model: magic\n")
    scenario("vehicle file missing", "vehicle: none.yaml\n")
    scenario("course file missing", "course: none.yaml\n")
    scenario("binary file", "\x00\x01\x02")
    out.append(
        Case(
            "scenario files",
            "duration 1e9 on the command line",
            ["simulate", "--duration", "1e9", *sim[1:]],
        )
    )
    out.append(Case("scenario files", "negative seed", ["simulate", "--seed", "-1", *sim[1:]]))
    out.append(Case("scenario files", "a folder as scenario", ["simulate", "{tmp}", *sim[1:]]))

    def layer(name, text, expect="error"):
        out.append(
            Case(
                "--with layering",
                name,
                [sim[0], "--with", "{tmp}/l.yaml", *sim[1:]],
                expect,
                {"l.yaml": text},
            )
        )

    layer("unknown nested field", "nmpc: {horizont: 30}\n")
    layer("not YAML", "rates: [: :\n")
    layer("a list", "- 1\n")
    layer("derived field", "clustering: {frame_rate_hz: 5.0}\n")
    layer("course beside the layer missing", "course: c.yaml\n")
    out.append(
        Case("--with layering", "layer missing", [sim[0], "--with", "{tmp}/none.yaml", *sim[1:]])
    )

    def course(name, text, expect="error"):
        out.append(
            Case(
                "course YAML",
                name,
                [sim[0], "{tmp}/s.yaml", *sim[1:]],
                expect,
                {"s.yaml": "course: c.yaml\nduration_s: 0.2\nlaps: null\n", "c.yaml": text},
            )
        )

    course("not YAML", "radius_m: [: :\n")
    course("a list", "- 1\n")
    course("unknown field", "no_such_field: 3\n")
    out.append(
        Case(
            "course YAML",
            "unknown shipped name",
            [sim[0], "{tmp}/s.yaml", *sim[1:]],
            files={"s.yaml": "course: nowhere\n"},
        )
    )

    fit_vehicle = ["fit", "{tmp}/never_read.csv", "--vehicle", "{tmp}/car.yaml"]
    for name, changes in [
        ("g = 0", {"g": 0.0}),
        ("g < 0", {"g": -9.81}),
        ("boolean mass", {"m": True}),
        ("text mass", {"m": "heavy"}),
        ("10 rad steering", {"delta_max": 10.0}),
        ("100 m centre of gravity", {"h": 100.0}),
        ("50 m front axle", {"lf": 50.0}),
        ("mu 0", {"mu": 0.0}),
        ("steering rate 100 rad/s", {"delta_dot_max": 100.0}),
        ("wheelbase longer than the car", {"length": 0.3}),
        ("unknown field", {"bogus": 3}),
    ]:
        out.append(Case("vehicle YAML", name, fit_vehicle, files={"car.yaml": _vehicle(**changes)}))
    out.append(Case("vehicle YAML", "not YAML", fit_vehicle, files={"car.yaml": "m: [: :\n"}))
    out.append(Case("vehicle YAML", "unknown preset", ["fit", "{tmp}/x.csv", "--vehicle", "kart"]))

    replay = ["replay", "{copy}", "--out", "{tmp}/replayed", "--no-progress"]

    def damaged_run(name, damage, expect="error"):
        out.append(
            Case("replay of damaged run folders", name, replay, expect, damage=("run", damage))
        )

    frames = lambda f: sorted((f / "frames").glob("*.png"))  # noqa: E731
    damaged_run("no drive log", lambda f: (f / "drive_log.csv").unlink())
    damaged_run("no scenario.yaml", lambda f: (f / "scenario.yaml").unlink())
    damaged_run("garbled scenario.yaml", lambda f: (f / "scenario.yaml").write_text("[: :"))
    damaged_run("empty drive log", lambda f: (f / "drive_log.csv").write_text(""))
    cut = (
        lambda f, n: (f / "drive_log.csv").write_text(  # noqa: E731 (a killed writer)
            "\n".join((f / "drive_log.csv").read_text().splitlines()[:6])[:-n] + "\n"
        )
    )
    damaged_run("drive log cut in a row's state", lambda f: cut(f, 1590))
    damaged_run("drive log cut in a row's features (that row skipped)", lambda f: cut(f, 300), "ok")
    damaged_run("garbled samples", lambda f: (f / "fitter_samples.npz").write_bytes(b"x"))
    damaged_run("a frame missing", lambda f: frames(f)[0].unlink())
    damaged_run(
        "a frame unreadable (stops early)", lambda f: frames(f)[-1].write_bytes(b"x"), "stopped"
    )
    damaged_run("no samples (not exact, said)", lambda f: (f / "fitter_samples.npz").unlink(), "ok")
    out.append(
        Case(
            "replay of damaged run folders",
            "not a folder or a log",
            ["replay", "{tmp}/none", "--out", "{tmp}/r"],
        )
    )
    out.append(
        Case(
            "replay of damaged run folders",
            "--out is the source",
            ["replay", "{copy}", "--out", "{copy}"],
            damage=("run", lambda f: None),
        )
    )

    report = ["evaluate", "--report", "{copy}"]

    def damaged_results(name, damage, expect="error"):
        out.append(
            Case(
                "evaluate --report on damaged folders",
                name,
                report,
                expect,
                damage=("results", damage),
            )
        )

    run0 = "runs/paper_sim__pcvfe__s000"
    damaged_results("runs.parquet garbled", lambda f: (f / "runs.parquet").write_text("x"))
    damaged_results("runs.parquet empty", lambda f: (f / "runs.parquet").write_bytes(b""))
    damaged_results(
        "runs.parquet another table",
        lambda f: pd.DataFrame({"a": [1]}).to_parquet(f / "runs.parquet"),
    )
    damaged_results("runs.parquet missing", lambda f: (f / "runs.parquet").unlink())
    damaged_results("laps.parquet garbled", lambda f: (f / "laps.parquet").write_text("x"))
    damaged_results("experiment.yaml garbled", lambda f: (f / "experiment.yaml").write_text("[:"))
    damaged_results("experiment.yaml a list", lambda f: (f / "experiment.yaml").write_text("- 1"))
    damaged_results("environment.json garbled", lambda f: (f / "environment.json").write_text("{"))
    damaged_results(
        "a drive log garbled (drawn around)",
        lambda f: (f / run0 / "drive_log.parquet").write_text("x"),
        "ok",
    )
    damaged_results(
        "a drive log missing (drawn around)",
        lambda f: (f / run0 / "drive_log.parquet").unlink(),
        "ok",
    )
    damaged_results(
        "a summary.json garbled (tables used)",
        lambda f: (f / run0 / "summary.json").write_text("{"),
        "ok",
    )
    damaged_results(
        "a scenario.yaml garbled (no map)",
        lambda f: (f / run0 / "scenario.yaml").write_text("[:"),
        "ok",
    )
    damaged_results("runs/ missing (drawn around)", lambda f: shutil.rmtree(f / "runs"), "ok")
    out.append(
        Case(
            "evaluate --report on damaged folders",
            "an empty folder",
            ["evaluate", "--report", "{tmp}"],
        )
    )

    bag = ["import-bag", "{copy}", "--out", "{tmp}/log/drive.csv"]
    data = lambda f: next(f.glob("*.mcap"))  # noqa: E731 (named after the bag's folder)

    def damaged_bag(name, damage, extra=(), expect="error"):
        out.append(Case("import-bag", name, [*bag, *extra], expect, damage=("bag", damage)))

    damaged_bag("metadata.yaml not YAML", lambda f: (f / "metadata.yaml").write_text("a: [: :"))
    damaged_bag("metadata.yaml missing", lambda f: (f / "metadata.yaml").unlink())
    damaged_bag("metadata.yaml empty", lambda f: (f / "metadata.yaml").write_text(""))
    damaged_bag("metadata.yaml a list", lambda f: (f / "metadata.yaml").write_text("- a\n"))
    damaged_bag(
        "metadata.yaml without files",
        lambda f: (f / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n"),
    )
    damaged_bag("storage file missing", lambda f: data(f).unlink())
    damaged_bag("storage file empty", lambda f: data(f).write_bytes(b""))
    damaged_bag("storage file noise", lambda f: data(f).write_bytes(os.urandom(4000)))
    damaged_bag(
        "storage file truncated",
        lambda f: data(f).write_bytes(data(f).read_bytes()[: data(f).stat().st_size // 2]),
    )
    for frac in (0.2, 0.5, 0.65, 0.8):
        damaged_bag(f"zeroed chunk at {frac:.0%}", lambda f, x=frac: _zero(data(f), x, 4096))
    damaged_bag(
        "zeroed chunk at 65 %, --lenient", lambda f: _zero(data(f), 0.65, 4096), ["--lenient"], "ok"
    )
    damaged_bag(
        "metadata counts more messages",
        lambda f: (f / "metadata.yaml").write_text(
            (f / "metadata.yaml").read_text().replace("message_count: 300", "message_count: 400")
        ),
    )
    out.append(
        Case(
            "import-bag",
            "a mapped topic not in the bag",
            [*bag, "--mapping", "{tmp}/m.yaml"],
            files={"m.yaml": "imu: {topic: /imu}\n"},
            damage=("bag", lambda f: None),
        )
    )
    out.append(
        Case("import-bag", "no such bag", ["import-bag", "{tmp}/none", "--out", "{tmp}/x.csv"])
    )

    features = lambda *a: ["features", *a]  # noqa: E731
    for name, args, files in [
        ("missing image", features("{tmp}/none.png"), {}),
        ("not an image", features("{tmp}/t.png"), {"t.png": "text"}),
        ("a folder", features("{tmp}"), {}),
        ("--top 0", features("{tmp}/t.png", "--top", "0"), {"t.png": "text"}),
        ("missing CLIP folder", features("{tmp}/t.png", "--clip", "{tmp}/none"), {"t.png": "t"}),
        ("negative lambda", features("{tmp}/t.png", "--lambda-c", "-1"), {"t.png": "t"}),
        ("NaN lambda", features("{tmp}/t.png", "--lambda-c", "nan"), {"t.png": "t"}),
    ]:
        out.append(Case("features", name, args, files=files))

    for command in ("fit", "diagnose"):
        for rate in ("1e6", "1001", "0", "-5", "nan"):
            out.append(
                Case(
                    "diagnose / fit",
                    f"{command} --resample {rate}",
                    [command, "{log}", "--resample", rate],
                )
            )
        out.append(Case("diagnose / fit", f"{command} on a missing log", [command, "{tmp}/n.csv"]))
        out.append(
            Case(
                "diagnose / fit",
                f"{command} on a binary log",
                [command, "{tmp}/b.csv"],
                files={"b.csv": "\x00\x01\x02\x03"},
            )
        )
    return out


# ----------------------------------------------------------------------------- more cases
def _png(width: int = 48, height: int = 48, mode: str = "RGB", fmt: str = "PNG") -> bytes:
    from PIL import Image

    rng = np.random.default_rng(0)
    pixels = rng.integers(0, 255, (height, width, 3), dtype=np.uint8)
    image = Image.fromarray(pixels, "RGB").convert(mode)
    buffer = io.BytesIO()
    image.save(buffer, fmt)
    return buffer.getvalue()


def _png16() -> bytes:
    """A 16-bit grey PNG using the whole range (a machine-vision camera's)."""
    from PIL import Image

    rng = np.random.default_rng(1)
    pixels = rng.integers(0, 65535, (48, 48), dtype=np.uint16)
    buffer = io.BytesIO()
    Image.fromarray(pixels).save(buffer, "PNG")
    return buffer.getvalue()


def _png_claiming(width: int, height: int) -> bytes:
    """A small PNG whose header claims ``width`` x ``height`` pixels (a decompression bomb)."""
    import struct
    import zlib

    data = bytearray(_png(1, 1))
    data[16:24] = struct.pack(">II", width, height)
    data[29:33] = struct.pack(">I", zlib.crc32(bytes(data[12:29])))
    return bytes(data)


def _course(change=None, segments=None, **fields) -> str:
    """The shipped slalom course as text, with ``fields`` changed, ``segments`` replaced, and
    ``change(data)`` applied last."""
    from importlib import resources

    text = resources.files("pcvfe_drake").joinpath("data/courses/slalom.yaml").read_text()
    data = yaml.safe_load(text)
    data.update(fields)
    if segments is not None:
        data["segments"] = segments
    if change is not None:
        change(data)
    return yaml.safe_dump(data)


def _straight_log(rows: int = 1000, v: float = 8.0) -> str:
    """A drive log of a straight at constant speed: no excitation of anything but drag."""
    t = np.arange(rows) * 0.01
    frame = pd.DataFrame({"t": t, "sx": v * t, "sy": 0 * t, "delta": 0 * t, "v": v + 0 * t})
    for column in ("psi", "psi_dot", "beta", "steer_rate", "accel"):
        frame[column] = 0 * t
    return frame.to_csv(index=False)


def _read_only(path: Path) -> None:
    """``path`` made read-only even for root (``chattr +i``; ``chmod`` where that fails)."""
    done = subprocess.run(["chattr", "+i", str(path)], capture_output=True)
    if done.returncode != 0:
        os.chmod(path, 0o555)


def _summary(rel: str):
    """A check: ``rel/summary.json`` was written and reads as JSON (else data lost)."""

    def check(tmp: Path, out: str, err: str):
        path = tmp / rel / "summary.json"
        try:
            json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            return "lost", f"no readable {rel}/summary.json ({exc})"
        return None

    return check


def _summary_seed(seed: int):
    """A check: the run's summary.json records ``seed`` as given (not wrapped or truncated)."""

    def check(tmp: Path, out: str, err: str):
        lost = _summary("run")(tmp, out, err)
        if lost is not None:
            return lost
        found = json.loads((tmp / "run" / "summary.json").read_text()).get("seed")
        return None if found == seed else ("wrong", f"summary.json seed {found!r}, not {seed}")

    return check


def _report_written(tmp: Path, out: str, err: str):
    """A check: ``evaluate --report`` wrote report.md in the damaged copy of the results."""
    report = tmp / "copy_results" / "report.md"
    return None if report.is_file() and report.stat().st_size > 0 else ("lost", "no report.md")


def _stays_under_runs(tmp: Path, out: str, err: str):
    """A check: the default run folder is one folder under ``runs/`` of the working directory."""
    runs = list(tmp.glob("runs/*/summary.json"))
    stray = [p for p in tmp.parent.rglob("summary.json") if tmp / "runs" not in p.parents]
    stray = [p for p in stray if "fixture_" not in str(p) and p.parent.parent != tmp.parent]
    if len(runs) != 1 or any(tmp in p.parents for p in stray):
        return "wrong", f"run folder not one folder under runs/: {runs} {stray}"
    if (tmp.parent / "escape").exists() or Path("/tmp/pcvfe_sweep_evil").exists():
        return "wrong", "the run folder left runs/"
    return None


def _stdout_says(*words: str, outcome: str = "wrong"):
    """A check: stdout (or stderr) holds every one of ``words``."""

    def check(tmp: Path, out: str, err: str):
        missing = [w for w in words if w not in out and w not in err]
        return (outcome, f"output does not say {missing}") if missing else None

    return check


def more_cases() -> list[Case]:
    """The cases beyond the first sweep's, to the issue's count per category and beyond."""
    out: list[Case] = []
    short = ["--duration", "0.2"]
    sim = ["simulate", "--no-meshcat", "--no-progress", "--out", "{tmp}/run"]
    ok_run = _summary("run")

    # ------------------------------------------------------------------ scenario files
    def scenario(
        name, text, expect="error", says=(), extra=(), check=None, args=None, in_file="s.yaml"
    ):
        files = {"s.yaml": text} if isinstance(text, str | bytes) else text
        cmd = args if args is not None else [sim[0], "{tmp}/s.yaml", *sim[1:]]
        if expect == "ok" and check is None and args is None:
            check = ok_run
        run_length = ("duration", "laps", "max_duration")
        if expect == "error" and args is None and not any(k in str(text) for k in run_length):
            extra = short  # nonsense accepted shows in a short run, not a lap
        out.append(
            Case(
                "scenario files",
                name,
                [*cmd, *extra],
                expect,
                files,
                says=(f"{{tmp}}/{in_file}", *says) if expect == "error" and args is None else says,
                check=check,
            )
        )

    ok = {"expect": "ok", "extra": short}
    # the document
    scenario("empty file (all defaults)", "", **ok)
    scenario("only comments (all defaults)", "# nothing to change\n", **ok)
    scenario("a bare string", "hello\n")
    scenario("a number", "42\n")
    scenario("tab-indented", "rates:\n\tcamera_period_s: 0.1\n")
    scenario("duplicate key", "seed: 1\nseed: 2\n", says=("seed",))
    scenario("a Python object tag", "!!python/object:os.system {}\n")
    scenario("Latin-1 bytes", "name: caf\xe9\n".encode("latin-1"), says=())
    scenario("UTF-8 BOM", "\ufeffseed: 1\n", **ok)
    scenario("CRLF line ends", "seed: 1\r\nname: crlf\r\n", **ok)
    scenario("JSON, not YAML", '{"seed": 2, "name": "json"}', **ok)
    scenario("an anchor and alias", "a: &x 1\nseed: *x\n", says=("'a'",))
    scenario("a folder named s.yaml", {"s.yaml/x": "seed: 1\n"}, says=())
    scenario(
        "a missing scenario file", {}, args=[sim[0], "{tmp}/none.yaml", *sim[1:]], says=("none")
    )
    scenario("a shipped name misspelled", {}, args=[sim[0], "paper_simm", *sim[1:]])
    scenario(
        "scenario at a path with spaces and accents",
        {"d é/s s.yaml": "seed: 1\n"},
        "ok",
        args=[sim[0], "{tmp}/d é/s s.yaml", *sim[1:], *short],
        check=ok_run,
    )
    # top-level fields
    scenario("empty name", "name: ''\n", says=("name",))
    scenario("a number as name", "name: 12\n", says=("name",))
    scenario("a list as description", "description: [a, b]\n", says=("description",))
    scenario(
        "an absolute path as name (default folder)",
        "name: /tmp/pcvfe_sweep_evil\n",
        "ok",
        args=["simulate", "{tmp}/s.yaml", "--no-meshcat", "--no-progress", *short],
        check=_stays_under_runs,
    )
    scenario(
        "a ../ name (default folder)",
        "name: ../escape\n",
        "ok",
        args=["simulate", "{tmp}/s.yaml", "--no-meshcat", "--no-progress", *short],
        check=_stays_under_runs,
    )
    scenario(
        "a name with a newline (default folder)",
        'name: "a\\nb"\n',
        "ok",
        args=["simulate", "{tmp}/s.yaml", "--no-meshcat", "--no-progress", *short],
        check=_stays_under_runs,
    )
    scenario("empty vehicle", "vehicle: ''\n", says=("vehicle",))
    scenario("a misspelled vehicle preset", "vehicle: ford\n", says=("ford",))
    scenario("a number as vehicle", "vehicle: 3\n", says=("vehicle",))
    scenario("unknown world", "world: moon\n", says=("moon",))
    scenario("a world file missing", "world: w.yaml\n", says=("w.yaml",))
    scenario(
        "a world file not YAML",
        {"s.yaml": "world: w.yaml\n", "w.yaml": "t: [: :\n"},
        in_file="w.yaml",
    )
    scenario(
        "a world file a list", {"s.yaml": "world: w.yaml\n", "w.yaml": "- 1\n"}, in_file="w.yaml"
    )
    scenario("negative terrain mu", "terrains: {sand: {mu: -0.5}}\n", says=("terrains.sand.mu",))
    scenario("NaN terrain mu", "terrains: {sand: {mu: .nan}}\n", says=("terrains.sand.mu",))
    scenario("terrain mu 50", "terrains: {sand: {mu: 50}}\n", says=("terrains.sand.mu",))
    scenario("a terrain not in the world", "terrains: {lava: {mu: 0.5}}\n", says=("lava",))
    scenario("unknown terrain field", "terrains: {sand: {friction: 0.5}}\n", says=("friction",))
    scenario("terrains a list", "terrains: [sand]\n", says=("terrains",))
    scenario("a number as course", "course: 5\n", says=("course",))
    scenario("truth model in capitals", "truth_model: MB\n", says=("truth_model",))
    scenario("fractional seed", "seed: 1.5\n", says=("seed",))
    scenario(
        "seed beyond 64 bits (numpy seeds take any integer; kept as given)",
        "seed: 99999999999999999999999\nname: bigseed\n",
        "ok",
        extra=short,
        check=_summary_seed(99999999999999999999999),
    )
    scenario("zero laps", "laps: 0\n", says=("laps",))
    scenario("infinite laps", "laps: .inf\n", says=("laps",))
    scenario("laps as words", "laps: two\n", says=("laps",))
    scenario("neither laps nor duration", "laps: null\n", says=("laps",))
    scenario("negative duration", "duration_s: -1\n", says=("duration_s",))
    scenario("zero duration", "duration_s: 0\n", says=("duration_s",))
    scenario("infinite duration", "duration_s: .inf\n", says=("duration_s",))
    scenario("duration with its unit", "duration_s: 5 s\n", says=("duration_s",))
    scenario("duration in milliseconds", "duration_s: 200ms\n", says=("duration_s",))
    scenario("a quoted number (read as a number)", 'duration_s: "0.2"\nname: quoted\n', "ok")
    scenario("a 1 ms run (summary still written)", "duration_s: 0.001\n", "ok")
    scenario("zero max duration", "max_duration_s: 0\n", says=("max_duration_s",))
    scenario("negative initial speed", "initial_speed_mps: -1\n", says=("initial_speed_mps",))
    scenario("initial speed 1000 m/s", "initial_speed_mps: 1000\n", says=("initial_speed_mps",))
    scenario("NaN start", "start_s_m: .nan\n", says=("start_s_m",))
    scenario("a start 1e12 m on (wrapped)", "start_s_m: 1.0e12\n", **ok)
    scenario(
        "0.3 s from a start on a transition strip (summary written)",
        "start_s_m: 128.0\nduration_s: 0.3\n",
        "ok",
    )
    out.append(
        Case(
            "scenario files",
            "a run folder's scenario.yaml from another directory",
            [sim[0], "{copy}/scenario.yaml", *sim[1:], *short],
            "ok",
            damage=("run", lambda f: None),
            check=ok_run,
        )
    )
    # rates
    scenario("zero camera period", "rates: {camera_period_s: 0}\n", says=("camera_period_s",))
    scenario("negative fitter period", "rates: {fitter_period_s: -1}\n", says=("fitter_period_s",))
    scenario(
        "fitter latency above its period",
        "rates: {fitter_latency_s: 2.0}\n",
        says=("rates.fitter_latency_s",),
    )
    scenario(
        "re-clustering faster than the camera",
        "rates: {recluster_period_s: 0.01}\n",
        says=("rates.recluster_period_s",),
    )
    scenario(
        "a frame saved every microsecond",
        "rates: {frame_log_period_s: 1.0e-6}\n",
        says=("rates.frame_log_period_s",),
    )
    scenario(
        "frame offset beyond the camera period",
        "rates: {clustering_frame_offset_s: 0.5}\n",
        says=("rates.clustering_frame_offset_s",),
    )
    scenario("a period as text with a unit", "rates: {log_period_s: 50 ms}\n", says=("log_period",))
    scenario("rates a list", "rates: [0.1, 0.05]\n", says=("rates",))
    scenario("NMPC period 10 s", "rates: {nmpc_period_s: 10.0}\n", says=("nmpc_period_s",))
    # simulator
    scenario(
        "unknown integrator",
        "simulator: {integration_scheme: euler_magic}\n",
        says=("integration_scheme",),
    )
    scenario("negative accuracy", "simulator: {accuracy: -1}\n", says=("simulator.accuracy",))
    scenario(
        "negative realtime rate",
        "simulator: {target_realtime_rate: -1}\n",
        says=("target_realtime_rate",),
    )
    scenario(
        "error control as text",
        "simulator: {use_error_control: maybe}\n",
        says=("use_error_control",),
    )
    # camera
    scenario("zero image width", "camera: {width_px: 0}\n", says=("width_px",))
    scenario("image width 100000", "camera: {width_px: 100000}\n", says=("width_px",))
    scenario("field of view 180 deg", "camera: {fov_deg: 180}\n", says=("fov_deg",))
    scenario("camera below the ground", "camera: {height_m: -1}\n", says=("height_m",))
    scenario("negative noise", "camera: {noise_std: -1}\n", says=("noise_std",))
    scenario("negative exposure", "camera: {exposure_s: -0.002}\n", says=("exposure_s",))
    # features
    scenario("empty feature backend", "features: {backend: ''}\n", says=("features.backend",))
    scenario("a CLIP folder missing", "features: {backend: clip_none}\n", says=("clip_none",))
    scenario("NaN lambda_c", "features: {lambda_c: .nan}\n", says=("features.lambda_c",))
    scenario("zero CLIP threads", "features: {clip_threads: 0}\n", says=("clip_threads",))
    # clustering
    scenario(
        "negative cluster duration",
        "clustering: {min_cluster_duration_s: -1}\n",
        says=("min_cluster_duration_s",),
    )
    scenario(
        "a billion stored frames", "clustering: {max_stored: 1000000000}\n", says=("max_stored",)
    )
    scenario("quantile 1.5", "clustering: {gate_quantile: 1.5}\n", says=("gate_quantile",))
    scenario(
        "novelty fraction 2", "clustering: {novelty_fraction: 2.0}\n", says=("novelty_fraction",)
    )
    # fitter
    scenario("zero fit horizon", "fitter: {horizon_steps: 0}\n", says=("horizon_steps",))
    scenario("fit horizon 1e6", "fitter: {horizon_steps: 1000000}\n", says=("horizon_steps",))
    scenario("zero stride", "fitter: {stride_steps: 0}\n", says=("stride_steps",))
    scenario("a buffer of 1e9 s", "fitter: {buffer_s: 1.0e9}\n", says=("buffer_s",))
    scenario("a billion windows", "fitter: {max_windows: 1000000000}\n", says=("max_windows",))
    scenario("zero iterations", "fitter: {max_iterations: 0}\n", says=("max_iterations",))
    scenario("a prior of two values", "fitter: {prior_theta: [1.0, 2.0]}\n", says=("prior_theta",))
    scenario("negative floor mu", "fitter: {handing: {floor_mu: -1}}\n", says=("floor_mu",))
    # nmpc
    scenario("zero horizon", "nmpc: {horizon: 0}\n", says=("horizon",))
    scenario("unknown NMPC model", "nmpc: {model: xyz}\n", says=("NmpcConfig.model",))
    scenario("speed margin 2", "nmpc: {speed_margin: 2.0}\n", says=("speed_margin",))
    scenario("zero friction margin", "nmpc: {friction_margin: 0}\n", says=("friction_margin",))
    scenario("negative solver tolerance", "nmpc: {eps_abs: -1}\n", says=("eps_abs",))
    scenario("max speed 1e6 m/s", "nmpc: {max_speed_mps: 1.0e6}\n", says=("max_speed_mps",))
    # the rest
    scenario("an LCM bus not defined", "hardware: {bus: nope}\n", says=("hardware.bus",))
    scenario(
        "zero hardware realtime rate", "hardware: {realtime_rate: 0}\n", says=("realtime_rate",)
    )
    scenario("unknown friction mapping", "friction_mapping: xyz\n", says=("friction_mapping",))
    scenario("unknown sensing model", "sensing: {model: gps}\n", says=("sensing.model",))
    scenario(
        "a sensing bias of one value",
        "sensing: {model: ins, bias: [0.0]}\n",
        says=("sensing.bias",),
    )
    scenario("unknown estimator", "estimator: magic\n", says=("estimator",))
    scenario(
        "negative fixed mu",
        "estimator: fixed\nfixed: {conservative_mu: -1}\n",
        says=("conservative_mu",),
    )
    scenario(
        "lookup with no classes",
        "estimator: lookup\nlookup: {classes: []}\n",
        says=("lookup.classes",),
    )
    scenario(
        "UKF bounds reversed",
        "estimator: ukf\nukf: {mu_bounds: [2.0, 0.05]}\n",
        says=("mu_bounds",),
    )
    scenario("stop_on_failure as text", "stop_on_failure: maybe\n", says=("stop_on_failure",))
    # the command line
    cli = lambda *a: ["simulate", "--no-meshcat", "--no-progress", *a]  # noqa: E731
    scenario("--seed as text", {}, args=cli("--seed", "abc", "--out", "{tmp}/run"))
    scenario("--duration -1", {}, args=cli("--duration", "-1", "--out", "{tmp}/run"))
    scenario("--duration nan", {}, args=cli("--duration", "nan", "--out", "{tmp}/run"))
    scenario("--laps 0", {}, args=cli("--laps", "0", "--out", "{tmp}/run"))
    scenario("a misspelled option", {}, args=cli("--durration", "1", "--out", "{tmp}/run"))
    scenario(
        "--out an existing file", {"f": "x"}, args=cli(*short, "--out", "{tmp}/f"), says=("f",)
    )
    out.append(
        Case(
            "scenario files",
            "--out under a read-only folder",
            cli(*short, "--out", "{tmp}/ro/run"),
            files={"ro/keep": "x"},
            says=("{tmp}/ro",),
            prepare=lambda tmp: _read_only(tmp / "ro"),
        )
    )
    scenario(
        "--out a 300-character name",
        {},
        args=cli(*short, "--out", "{tmp}/" + "x" * 300),
        says=("xxxx",),
    )
    scenario("--out an empty string", {}, args=cli(*short, "--out", ""))

    # --------------------------------------------------------------- --with layering
    def layer(name, files, args, expect="error", says=()):
        check = ok_run if expect == "ok" else None
        out.append(Case("--with layering", name, args, expect, files, says=says, check=check))

    with_ = (
        lambda *paths: [  # noqa: E731
            sim[0],
            *[x for p in paths for x in ("--with", p)],
            *sim[1:],
        ]
    )
    layer("an empty layer (no change)", {"l.yaml": ""}, [*with_("{tmp}/l.yaml"), *short], "ok")
    layer(
        "two layers, the second wins",
        {"a.yaml": "seed: 1\n", "b.yaml": "seed: 2\n"},
        [*with_("{tmp}/a.yaml", "{tmp}/b.yaml"), *short],
        "ok",
    )
    layer(
        "a wrong type in the second layer",
        {"a.yaml": "seed: 1\n", "b.yaml": "rates: {camera_period_s: fast}\n"},
        with_("{tmp}/a.yaml", "{tmp}/b.yaml"),
        says=("{tmp}/b.yaml", "rates.camera_period_s"),
    )
    layer("a folder as layer", {"d/x": ""}, with_("{tmp}/d"), says=("{tmp}/d",))
    layer("a binary layer", {"l.yaml": b"\x00\xff\xfe"}, with_("{tmp}/l.yaml"), says=("l.yaml",))
    layer(
        "a vehicle file beside the layer in another folder",
        {
            "sub/l.yaml": "vehicle: car.yaml\nestimator: pcvfe_paper\n",
            "sub/car.yaml": _vehicle(name="car"),
        },
        [*with_("{tmp}/sub/l.yaml"), *short],
        "ok",
    )
    layer(
        "a course file beside the layer in another folder",
        {"sub/l.yaml": "course: c.yaml\n", "sub/c.yaml": _course()},
        [*with_("{tmp}/sub/l.yaml"), *short],
        "ok",
    )
    layer(
        "the same layer twice",
        {"l.yaml": "seed: 3\n"},
        [*with_("{tmp}/l.yaml", "{tmp}/l.yaml"), *short],
        "ok",
    )
    layer(
        "a replaced field",
        {"l.yaml": "terrain_layout: paper\n"},
        with_("{tmp}/l.yaml"),
        says=("terrain_layout",),
    )
    layer(
        "a layer that unsets the run length",
        {"l.yaml": "laps: null\n"},
        with_("{tmp}/l.yaml"),
        says=("laps",),
    )
    layer("a shipped overlay by name", {}, [*with_("overlays/bmw_320i"), *short], "ok")
    layer("a shipped overlay misspelled", {}, with_("overlays/bmw320i"), says=("bmw320i",))

    # ------------------------------------------------------------------ course YAML
    def course(name, text, expect="error", says=(), vehicle=None):
        files = {"s.yaml": "course: c.yaml\nduration_s: 0.2\nlaps: null\n", "c.yaml": text}
        out.append(
            Case(
                "course YAML",
                name,
                [sim[0], "{tmp}/s.yaml", *sim[1:]],
                expect,
                files,
                says=("c.yaml", *says) if expect == "error" else (),
                check=ok_run if expect == "ok" else None,
            )
        )

    def seg(i, **changes):
        def change(data):
            data["segments"][i].update(changes)

        return change

    course("radius as a word", _course(seg(1, radius_m="twelve")), says=("radius_m",))
    course("closure tolerance 10 km", _course(closure_tol_m=10000.0), says=("closure_tol_m",))
    course(
        "an open course inside a huge tolerance",
        _course(lambda d: d["segments"].pop(), closure_tol_m=10000.0),
        says=("closure_tol_m",),
    )
    course("an open course", _course(lambda d: d["segments"].pop()), says=("do not close",))
    course("smoothing longer than the lap", _course(smoothing_m=5000.0), says=("smoothing_m",))
    course("2.5 waves", _course(seg(0, waves=2.5)), says=("waves",))
    course("zero waves", _course(seg(0, waves=0)), says=("waves",))
    course("no segments", _course(segments=[]), says=("segments",))
    course("unknown segment kind", _course(seg(2, kind="spiral")), says=("spiral",))
    course("zero arc radius", _course(seg(1, radius_m=0.0)), says=("radius_m",))
    course("NaN arc angle", _course(seg(1, angle_deg=float("nan"))), says=("angle_deg",))
    course("negative straight", _course(seg(2, length_m=-146.0)), says=("length_m",))
    course(
        "angles in radians",
        _course(
            lambda d: [s.update(angle_deg=1.5708) for s in d["segments"] if s["kind"] == "arc"]
        ),
        says=("close",),
    )
    course("zero spacing", _course(spacing_m=0.0), says=("spacing_m",))
    course("a micrometre spacing", _course(spacing_m=1.0e-6), says=("spacing_m",))
    course("spacing longer than the lap", _course(spacing_m=2000.0), says=("spacing_m",))
    course("zero half width", _course(half_width_m=0.0), says=("half_width_m",))
    course("negative speed", _course(speed_mps=-4.75), says=("speed_mps",))
    course(
        "NaN start heading", _course(start_heading_deg=float("nan")), says=("start_heading_deg",)
    )
    course(
        "a bend tighter than the car turns",
        yaml.safe_dump(
            {
                "name": "tight",
                "segments": [{"kind": "arc", "radius_m": 1.0, "angle_deg": 360.0}],
            }
        ),
        says=("tighter",),
    )
    course(
        "a figure of eight",
        yaml.safe_dump(
            {
                "name": "eight",
                "segments": [
                    {"kind": "arc", "radius_m": 20.0, "angle_deg": 360.0},
                    {"kind": "arc", "radius_m": 20.0, "angle_deg": -360.0},
                ],
            }
        ),
        says=("turning",),
    )
    course("segments a mapping", _course(segments={"kind": "straight"}), says=("segments",))
    course("an empty course file", "", says=())
    course(
        "a circle (accepted)",
        yaml.safe_dump(
            {
                "name": "circle",
                "segments": [{"kind": "arc", "radius_m": 25.0, "angle_deg": 360.0}],
                "speed_mps": 4.0,
            }
        ),
        "ok",
    )

    # ------------------------------------------------------------------ vehicle YAML (+ fit)
    fit_vehicle = ["fit", "{tmp}/never_read.csv", "--vehicle", "{tmp}/car.yaml"]
    nan, inf = float("nan"), float("inf")
    for name, changes, field in [
        ("negative mass", {"m": -3.5}, "m"),
        ("NaN mass", {"m": nan}, "m"),
        ("infinite yaw inertia", {"I_z": inf}, "I_z"),
        ("mass in grams", {"m": 1.2e6}, "m"),
        ("positive lower steering limit", {"delta_min": 0.4}, "delta_min"),
        ("zero top speed", {"v_max": 0.0}, "v_max"),
        ("negative track", {"track": -0.3}, "track"),
        ("zero width", {"width": 0.0}, "width"),
        ("acceleration 1000 m/s^2", {"a_max": 1000.0}, "a_max"),
        ("axle distance in cm", {"lf": 15.0}, "lf"),
        ("zero cornering stiffness", {"C_Sf": 0.0}, "C_Sf"),
        ("a number as name", {"name": 5}, "name"),
    ]:
        out.append(
            Case(
                "vehicle YAML",
                name,
                fit_vehicle,
                files={"car.yaml": _vehicle(**changes)},
                says=("car.yaml", field),
            )
        )

    def missing_mass():
        text = yaml.safe_load(_vehicle())
        text.pop("m")
        return yaml.safe_dump(text)

    for name, text in [
        ("a field missing", missing_mass()),
        ("an empty file", ""),
        ("a list", "- 1\n- 2\n"),
        ("garbled JSON", '{"m": 3.5,'),
    ]:
        out.append(
            Case("vehicle YAML", name, fit_vehicle, files={"car.yaml": text}, says=("car.yaml",))
        )
    in_scenario = [sim[0], "{tmp}/s.yaml", *sim[1:]]
    out.append(
        Case(
            "vehicle YAML",
            "a scenario's vehicle file out of range",
            in_scenario,
            files={"s.yaml": "vehicle: car.yaml\n", "car.yaml": _vehicle(g=0.0)},
            says=("car.yaml", "g"),
        )
    )
    out.append(
        Case(
            "vehicle YAML",
            "an effect model beside the scenario, run from elsewhere",
            [
                "simulate",
                "{tmp}/sub/s.yaml",
                "--no-meshcat",
                "--no-progress",
                "--out",
                "{tmp}/run",
                *short,
            ],
            "ok",
            files={
                "sub/s.yaml": "fitter: {model: {file: m.yaml}}\n",
                "sub/m.yaml": "effects: []\n",
            },
            check=ok_run,
        )
    )
    out.append(
        Case(
            "vehicle YAML",
            "a scenario's vehicle file in JSON (accepted)",
            [*in_scenario, *short],
            "ok",
            files={
                "s.yaml": "vehicle: car.json\nestimator: pcvfe_paper\n",
                "car.json": json.dumps(yaml.safe_load(_vehicle(name="car"))),
            },
            check=ok_run,
        )
    )
    model = lambda text: {  # noqa: E731
        "s.yaml": "fitter: {model: {file: m.yaml}}\n",
        "m.yaml": text,
    }
    for name, files, words in [
        ("an effect model file missing", {"s.yaml": "fitter: {model: {file: m.yaml}}\n"}, "m.yaml"),
        ("an effect model not YAML", model("effects: [: :\n"), "m.yaml"),
        ("an unknown effect", model("effects: [{name: warp_drive}]\n"), "warp_drive"),
        (
            "a negative effect std",
            model("effects: [{name: drag, fixed: {CdA: 0.1}, std: {CdA: -1.0}}]\n"),
            "std",
        ),
        ("an effect model with no effects key", model("vehicle: ford_escort\n"), "effects"),
        (
            "a key given twice in a vehicle file",
            {"s.yaml": "vehicle: c.yaml\n", "c.yaml": _vehicle() + "m: 3.0\n"},
            "'m'",
        ),
    ]:
        out.append(Case("vehicle YAML", name, in_scenario, files=files, says=(words,)))

    # ------------------------------------------------------------------ replay
    replay = ["replay", "{copy}", "--out", "{tmp}/replayed", "--no-progress"]

    def damaged_run(name, damage, expect="error", says=(), args=replay, prepare=None):
        check = _summary("replayed") if expect == "ok" and args is replay else None
        out.append(
            Case(
                "replay of damaged run folders",
                name,
                args,
                expect,
                damage=("run", damage),
                says=says,
                check=check,
                prepare=prepare,
            )
        )

    def log_edit(edit):
        def damage(f):
            frame = pd.read_csv(f / "drive_log.csv")
            edit(frame).to_csv(f / "drive_log.csv", index=False)

        return damage

    damaged_run(
        "a state column removed", log_edit(lambda d: d.drop(columns=["v"])), says=("drive_log",)
    )
    damaged_run(
        "a NaN speed mid-log",
        log_edit(lambda d: d.assign(v=d["v"].where(d.index != 20))),
        says=("drive_log",),
    )
    damaged_run(
        "rows out of time order",
        log_edit(lambda d: d.iloc[::-1]),
        says=("drive_log",),
    )
    damaged_run(
        "rows repeated", log_edit(lambda d: pd.concat([d, d.iloc[:5]])), says=("drive_log",)
    )
    damaged_run("header only", log_edit(lambda d: d.iloc[:0]), says=("drive_log",))
    damaged_run(
        "scenario.yaml with an unknown field",
        lambda f: (f / "scenario.yaml").write_text(
            (f / "scenario.yaml").read_text() + "no_such_field: 1\n"
        ),
        says=("scenario.yaml", "no_such_field"),
    )
    damaged_run(
        "scenario.yaml names a vehicle file that is gone",
        lambda f: (f / "scenario.yaml").write_text(
            (f / "scenario.yaml").read_text().replace("vehicle: ford_escort", "vehicle: gone.yaml")
        ),
        says=("gone.yaml",),
    )
    damaged_run(
        "summary.json garbled (not needed)",
        lambda f: (f / "summary.json").write_text("{"),
        "ok",
    )
    damaged_run("frames/ removed", lambda f: shutil.rmtree(f / "frames"), says=("frame",))
    damaged_run(
        "the drive log alone (needs --scenario)",
        lambda f: None,
        args=["replay", "{copy}/drive_log.csv", "--out", "{tmp}/replayed", "--no-progress"],
        says=("--scenario",),
    )
    damaged_run(
        "the drive log with --scenario",
        lambda f: None,
        "ok",
        args=[
            "replay",
            "{copy}/drive_log.csv",
            "--scenario",
            "paper_sim",
            "--out",
            "{tmp}/replayed",
            "--no-progress",
        ],
    )
    damaged_run(
        "a drive log with a scenario missing",
        lambda f: None,
        args=[
            "replay",
            "{copy}/drive_log.csv",
            "--scenario",
            "{tmp}/none.yaml",
            "--out",
            "{tmp}/r",
        ],
        says=("none.yaml",),
    )
    damaged_run(
        "--out under a read-only folder",
        lambda f: None,
        args=["replay", "{copy}", "--out", "{tmp}/ro/r", "--no-progress"],
        says=("{tmp}/ro",),
        prepare=lambda tmp: ((tmp / "ro").mkdir(), _read_only(tmp / "ro")),
    )

    # ------------------------------------------------------------------ evaluate --report
    def damaged_results(name, damage, expect="error", says=(), args=None, prepare=None, check=None):
        out.append(
            Case(
                "evaluate --report on damaged folders",
                name,
                args or ["evaluate", "--report", "{copy}"],
                expect,
                damage=("results", damage),
                says=says,
                prepare=prepare,
                check=check,
            )
        )

    damaged_results("laps.parquet missing", lambda f: (f / "laps.parquet").unlink(), "ok")
    damaged_results(
        "experiment.yaml missing (named after the folder)",
        lambda f: (f / "experiment.yaml").unlink(),
        "ok",
        check=_report_written,
    )
    damaged_results(
        "runs.parquet with no rows",
        lambda f: pd.read_parquet(f / "runs.parquet").iloc[:0].to_parquet(f / "runs.parquet"),
        says=("runs.parquet",),
    )
    damaged_results(
        "a file, not a folder",
        lambda f: None,
        args=["evaluate", "--report", "{copy}/runs.parquet"],
        says=("runs.parquet",),
    )
    damaged_results(
        "a read-only results folder",
        lambda f: _read_only(f),
        says=("copy_results",),
    )

    # ------------------------------------------------------------------ import-bag
    bag = ["import-bag", "{copy}", "--out"]
    for name, args, files, says, prepare in [
        ("--out a .txt file", [*bag, "{tmp}/drive.txt"], {}, "drive.txt", None),
        (
            "a mapping not YAML",
            [*bag, "{tmp}/d.csv", "--mapping", "{tmp}/m.yaml"],
            {"m.yaml": "imu: [: :\n"},
            "m.yaml",
            None,
        ),
        (
            "an unknown shipped mapping",
            [*bag, "{tmp}/d.csv", "--mapping", "ros3"],
            {},
            "ros3",
            None,
        ),
        (
            "a mapping with an unknown field",
            [*bag, "{tmp}/d.csv", "--mapping", "{tmp}/m.yaml"],
            {"m.yaml": "odometry: {topic: /odom, frame: x}\nwheels: {topic: /w}\n"},
            "m.yaml",
            None,
        ),
        (
            "--out under a read-only folder",
            [*bag, "{tmp}/ro/d.csv"],
            {"ro/keep": "x"},
            "{tmp}/ro",
            lambda tmp: _read_only(tmp / "ro"),
        ),
    ]:
        out.append(
            Case(
                "import-bag",
                name,
                args,
                files=files,
                damage=("bag", lambda f: None),
                says=(says,),
                prepare=prepare,
            )
        )
    out.append(
        Case(
            "import-bag",
            "a file, not a bag folder",
            ["import-bag", "{tmp}/b.mcap", "--out", "{tmp}/d.csv"],
            files={"b.mcap": b"\x89MCAP0\r\n" + bytes(100)},
            says=("b.mcap",),
        )
    )

    # ------------------------------------------------------------------ features
    png = _png()

    def feature(name, args, files=None, expect="error", says=()):
        out.append(Case("features", name, ["features", *args], expect, files, says=says))

    feature("an empty file", ["{tmp}/e.png"], {"e.png": b""}, says=("e.png",))
    feature("a truncated PNG", ["{tmp}/t.png"], {"t.png": png[:100]}, says=("t.png",))
    feature(
        "a decompression bomb",
        ["{tmp}/b.png"],
        {"b.png": _png_claiming(60000, 60000)},
        says=("b.png",),
    )
    feature("a 1 x 1 image", ["{tmp}/p.png"], {"p.png": _png(1, 1)}, says=("p.png",))
    feature("grayscale", ["{tmp}/g.png"], {"g.png": _png(mode="L")}, "ok")
    feature("with alpha", ["{tmp}/a.png"], {"a.png": _png(mode="RGBA")}, "ok")
    feature("16-bit", ["{tmp}/w.png"], {"w.png": _png16()}, "ok")
    feature("a JPEG named .png", ["{tmp}/j.png"], {"j.png": _png(fmt="JPEG")}, "ok")
    feature("a PNG named .txt", ["{tmp}/p.txt"], {"p.txt": png}, "ok")
    feature("a GIF", ["{tmp}/g.gif"], {"g.gif": _png(mode="P", fmt="GIF")}, "ok")
    feature("a CMYK JPEG", ["{tmp}/c.jpg"], {"c.jpg": _png(mode="CMYK", fmt="JPEG")}, "ok")
    feature(
        "infinite lambda", ["{tmp}/i.png", "--lambda-c", "inf"], {"i.png": png}, says=("lambda",)
    )
    feature("lambda as text", ["{tmp}/i.png", "--lambda-c", "much"], {"i.png": png})
    feature("--top -1", ["{tmp}/i.png", "--top", "-1"], {"i.png": png}, says=("top",))
    feature(
        "an empty CLIP folder",
        ["{tmp}/i.png", "--clip", "{tmp}/clip"],
        {"i.png": png, "clip/.keep": ""},
        says=("clip",),
    )
    feature(
        "a file as CLIP folder",
        ["{tmp}/i.png", "--clip", "{tmp}/i.png"],
        {"i.png": png},
        says=("i.png",),
    )
    feature("a folder named .png", ["{tmp}/d.png"], {"d.png/x": ""}, says=("d.png",))
    feature(
        "50 images at once",
        [f"{{tmp}}/i{k}.png" for k in range(50)],
        {f"i{k}.png": png for k in range(50)},
        "ok",
    )
    feature("a path with spaces and accents", ["{tmp}/d é/i m.png"], {"d é/i m.png": png}, "ok")
    feature("an unknown backend", ["{tmp}/i.png", "--backend", "xyz"], {"i.png": png})

    # ------------------------------------------------------------------ diagnose / fit
    def log_case(name, args, expect="error", files=None, damage=None, says=(), check=None):
        out.append(
            Case(
                "diagnose / fit",
                name,
                args,
                expect,
                files,
                damage=("log", damage) if damage is not None else None,
                says=says,
                check=check,
            )
        )

    def csv_edit(edit):
        def damage(f):
            edit(pd.read_csv(f)).to_csv(f, index=False)

        return damage

    straight = {"s.csv": _straight_log(rows=4000)}
    log_case("fit an empty log", ["fit", "{tmp}/e.csv"], files={"e.csv": ""}, says=("e.csv",))
    log_case(
        "fit a header-only log",
        ["fit", "{copy}"],
        damage=csv_edit(lambda d: d.iloc[:0]),
        says=("copy_log",),
    )
    log_case(
        "fit a log of 3 rows (no fit, said)",
        ["fit", "{copy}"],
        "ok",
        damage=csv_edit(lambda d: d.iloc[:3]),
        check=_stdout_says("no fit", "too little data"),
    )
    log_case(
        "fit a log without speed",
        ["fit", "{copy}"],
        damage=csv_edit(lambda d: d.drop(columns=["v"])),
        says=("copy_log", "v"),
    )
    nan_rows = csv_edit(lambda d: d.assign(v=d["v"].where(d.index % 97 != 5)))
    log_case("fit a log with NaN rows", ["fit", "{copy}"], damage=nan_rows, says=("copy_log",))
    log_case(
        "fit --lenient a log with NaN rows", ["fit", "{copy}", "--lenient"], "ok", damage=nan_rows
    )
    log_case(
        "fit a log with time going back",
        ["fit", "{copy}"],
        damage=csv_edit(lambda d: d.assign(t=d["t"][::-1].to_numpy())),
        says=("copy_log",),
    )
    degrees = csv_edit(
        lambda d: d.assign(delta=np.degrees(d["delta"]), psi_dot=np.degrees(d["psi_dot"]))
    )
    log_case("fit a log in degrees", ["fit", "{copy}"], damage=degrees, says=("copy_log",))
    log_case(
        "diagnose a log in degrees",
        ["diagnose", "{copy}", "--candidates", "drag"],
        damage=degrees,
        says=("copy_log",),
    )
    log_case(
        "diagnose a straight at constant speed (no verdict)",
        ["diagnose", "{tmp}/s.csv", "--candidates", "drag"],
        files=straight,
        says=("s.csv",),
    )
    log_case(
        "fit a straight at constant speed (not identifiable)",
        ["fit", "{tmp}/s.csv"],
        "ok",
        files=straight,
        check=_stdout_says("not identifiable"),
    )
    for option, value, word in [
        ("--horizon", "0", "horizon"),
        ("--stride", "0", "stride"),
        ("--min-speed", "-1", "min-speed"),
        ("--max-windows", "-5", "max-windows"),
        ("--effects", "warp_drive", "warp_drive"),
        ("--effects", "steering_lag:tau", "steering_lag:tau"),
        ("--context-column", "none_such", None),
        ("--model-error-rel", "nan", "model_error_rel"),
        ("--scenario", "{tmp}/none.yaml", "none.yaml"),
    ]:
        log_case(
            f"fit {option} {value}", ["fit", "{log}", option, value], says=(word,) if word else ()
        )
    log_case(
        "fit --joint --prior-rel -1",
        ["fit", "{log}", "--joint", "--prior-rel", "-1"],
        says=("prior-rel",),
    )
    log_case(
        "diagnose --add warp_drive",
        ["diagnose", "{log}", "--add", "warp_drive"],
        says=("warp_drive",),
    )
    log_case(
        "diagnose --candidates warp_drive",
        ["diagnose", "{log}", "--candidates", "warp_drive"],
        says=("warp_drive",),
    )
    log_case(
        "diagnose --effects-file missing",
        ["diagnose", "{log}", "--effects-file", "{tmp}/none.py"],
        says=("none.py",),
    )
    out.append(
        Case(
            "diagnose / fit",
            "diagnose --out under a read-only folder",
            ["diagnose", "{log}", "--candidates", "drag", "--out", "{tmp}/ro/report"],
            files={"ro/keep": ""},
            says=("{tmp}/ro",),
            prepare=lambda tmp: _read_only(tmp / "ro"),
        )
    )
    log_case(
        "fit a garbled parquet",
        ["fit", "{tmp}/g.parquet"],
        files={"g.parquet": b"PAR1x"},
        says=("g.parquet",),
    )
    return out
