"""The problem specs shipped with cvxid (package data ``cvxid.problems``, the repository's
``problems/`` folder): ``cvxid problems`` lists them and ``cvxid run NAME`` finds one from
any folder."""

from __future__ import annotations

import re
from importlib.resources import files
from pathlib import Path

import pandas as pd

from cvxid.errors import CvxidError
from cvxid.spec.toml import tomllib


def shipped_folder() -> Path:
    """The folder of the installed problem specs."""
    return Path(str(files("cvxid.problems")))


def shipped_problems() -> dict[str, Path]:
    """Every shipped spec by name (its file name without ``.toml``), sorted."""
    return {p.stem: p for p in sorted(shipped_folder().glob("*.toml"))}


def resolve_spec(name_or_path: str) -> Path:
    """The spec file ``name_or_path`` names: an existing file, else a shipped problem's name
    (with or without ``.toml``); an error listing the shipped names otherwise."""
    path = Path(name_or_path)
    if path.is_file():
        return path
    shipped = shipped_problems()
    name = path.name[: -len(".toml")] if path.name.endswith(".toml") else path.name
    if path.parent == Path(".") and name in shipped:
        return shipped[name]
    raise CvxidError(f"spec file not found: {name_or_path} (and it is not a shipped problem: "
                     f"{', '.join(shipped)}; `cvxid problems` lists them)")


def _summary(path: Path) -> tuple[str, str]:
    """A spec's one-line summary (the first clause of its header comment, else its
    description) and where its data come from."""
    text = path.read_text(encoding="utf-8")
    raw = tomllib.loads(text)
    header = []
    for line in text.splitlines():
        if not line.startswith("#"):
            break
        header.append(line.lstrip("# ").strip())
    summary = re.split(r"[.:;] |[.:;]$", " ".join(header) + " ", maxsplit=1)[0] if header else ""
    summary = summary or str(raw.get("description", ""))
    files_ = [d["file"] for d in raw.get("data", {}).values() if isinstance(d, dict) and "file" in d]
    if not files_:
        return summary, "simulated"
    missing = [f for f in files_ if not (path.parent / f).is_file()]
    return summary, f"needs {Path(missing[0]).name}" if missing else "file"


def problems_table() -> pd.DataFrame:
    """The shipped problems: name, where the data come from, one line on each."""
    rows = []
    for name, path in shipped_problems().items():
        summary, data = _summary(path)
        rows.append({"problem": name, "data": data, "what it shows": summary})
    return pd.DataFrame(rows).set_index("problem")
