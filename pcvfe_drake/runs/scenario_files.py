"""Where scenario files are: the shipped ones and user files (light: no config imports).

``pcvfe --help`` lists the shipped scenarios without importing the configs the scenario embeds
(the clustering's scikit-learn alone takes seconds to import); ``pcvfe_drake.runs.scenario``
re-exports these names.
"""

from __future__ import annotations

from pathlib import Path

SCENARIO_DIR = Path(__file__).resolve().parents[1] / "data" / "scenarios"
"""Folder of the shipped scenario files."""

DEFAULT_SCENARIO = "paper_sim"
"""The scenario of ``pcvfe simulate`` without arguments (and of ``make run``)."""


def shipped_scenarios() -> list[str]:
    """Names of the scenarios shipped in ``pcvfe_drake/data/scenarios``."""
    return sorted(p.stem for p in SCENARIO_DIR.glob("*.yaml"))


def resolve_scenario_path(path_or_name: str | Path | None) -> Path:
    """The YAML file of a scenario given as a file path or a shipped scenario name.

    None means the default scenario. Raises FileNotFoundError naming the input and the shipped
    scenarios when neither exists.
    """
    if path_or_name is None:
        path_or_name = DEFAULT_SCENARIO
    candidate = Path(path_or_name).expanduser()
    if candidate.is_file():
        return candidate.resolve()
    if candidate.is_dir():
        raise FileNotFoundError(
            f"scenario {str(path_or_name)!r} is a folder; give a scenario YAML file or one of "
            f"the shipped scenarios ({', '.join(shipped_scenarios())})"
        )
    shipped = SCENARIO_DIR / f"{path_or_name}.yaml"
    if shipped.is_file():
        return shipped
    raise FileNotFoundError(
        f"scenario {str(path_or_name)!r} is neither a file nor a shipped scenario "
        f"(shipped: {', '.join(shipped_scenarios())})"
    )


def resolve_file_field(value: str, named_in: Path, field: str) -> str:
    """A file path written in the scenario file ``named_in`` (field ``field``) as an absolute
    path: a relative path is taken relative to that file's folder (not the working directory),
    so a scenario and the files it names move together and a run folder's ``scenario.yaml``
    (which stores the absolute path) runs from any directory. Raises FileNotFoundError naming
    the scenario file, the field and the path tried when it is not a file."""
    path = Path(value).expanduser()
    if not path.is_absolute():
        path = Path(named_in).parent / path
    if not path.is_file():
        raise FileNotFoundError(
            f"{named_in}: field {field!r}={value!r} is not a file ({path}; a relative path is "
            "taken relative to the scenario file)"
        )
    return str(path.resolve())
