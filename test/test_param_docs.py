"""scripts/param_docs.py: the plugin pages' parameter tables match the parameter classes, and a stale one is caught."""

from __future__ import annotations

import dataclasses
import importlib.util
import re
import subprocess
import sys
import textwrap
from pathlib import Path
from typing import Annotated, Literal

import pydantic
from pydantic import Field

from lidar_weather_sim.core.config import ConfigModel

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / "scripts" / "param_docs.py"
DROR_PAGE = "src/weather_filter/docs/filters/dror.md"


def _load_script():
    spec = importlib.util.spec_from_file_location("param_docs", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules["param_docs"] = module
    spec.loader.exec_module(module)
    return module


pd = _load_script()


def run(*args, cwd=REPO):
    return subprocess.run([sys.executable, str(SCRIPT), *args], cwd=cwd, capture_output=True, text=True, timeout=300)


def test_every_page_is_up_to_date():
    """Fails when a parameter was added, removed or re-described without ``python scripts/param_docs.py``."""
    done = run("--check")
    assert done.returncode == 0, done.stderr
    for page in pd.PAGES:
        text = (REPO / page.path).read_text()
        assert text.count(pd.BEGIN) == 1 and "| parameter | type | default | constraint | description |" in text, page.path


def test_a_tampered_table_is_reported_and_repaired(tmp_path):
    original = (REPO / DROR_PAGE).read_text()
    page = tmp_path / DROR_PAGE
    page.parent.mkdir(parents=True)
    page.write_text(original)
    assert run("--check", "--root", str(tmp_path), "--only", "dror").returncode == 0  # the copy itself is fine
    row = "| `multiplier` | float | `3.0` |"
    assert original.count(row) == 1
    page.write_text(original.replace(row, "| `multiplier` | float | `2.0` |"))
    done = run("--check", "--root", str(tmp_path), "--only", "dror")
    assert done.returncode == 1
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and DROR_PAGE in lines[0] and "out of date" in lines[0]
    assert "`2.0`" in page.read_text(), "--check must not write"
    assert run("--root", str(tmp_path), "--only", "dror").returncode == 0
    assert page.read_text() == original


def test_a_parameter_added_without_regenerating_fails_the_check(tmp_path):
    source = tmp_path / "my_params.py"
    page = tmp_path / "my_page.md"
    page.write_text("# My plugin\n\nText before.\n\n<!-- params:begin -->\n<!-- params:end -->\n\nText after.\n")
    source.write_text(textwrap.dedent("""
        from pydantic import Field
        from lidar_weather_sim.core.config import ConfigModel

        class MyParams(ConfigModel):
            gain: float = Field(1.0, gt=0, description="Multiplies the signal (-)")
    """))
    spec = f"{page}={source}:MyParams"
    assert run("--page", spec).returncode == 0
    written = page.read_text()
    assert written.startswith("# My plugin\n\nText before.\n\n<!-- params:begin -->\n")
    assert written.endswith("<!-- params:end -->\n\nText after.\n")
    assert "| `gain` | float | `1.0` | > 0 | Multiplies the signal (-) |" in written
    assert run("--check", "--page", spec).returncode == 0
    source.write_text(source.read_text() + '    offset_m: float = Field(0.0, ge=-1, le=1, description="Added later (m)")\n')
    done = run("--check", "--page", spec)
    assert done.returncode == 1 and str(page) in done.stderr
    assert run("--page", spec).returncode == 0
    assert "| `offset_m` | float | `0.0` | >= -1, <= 1 | Added later (m) |" in page.read_text()


def test_a_page_without_markers_is_named(tmp_path):
    page = tmp_path / DROR_PAGE
    page.parent.mkdir(parents=True)
    page.write_text("# DROR\n\nno table here\n")
    done = run("--check", "--root", str(tmp_path), "--only", "dror")
    assert done.returncode == 1 and DROR_PAGE in done.stderr and "params:begin" in done.stderr


NonNegative = Annotated[float, Field(ge=0, strict=True, allow_inf_nan=False)]


class Inner(ConfigModel):
    k: int = Field(3, ge=1, description="neighbours")


class Outer(ConfigModel):
    radius_m: NonNegative | None = Field(None, description="a | b <c>")
    mode: Literal["a", "b"] = Field("a", description="which")
    needed: float = Field(gt=0, lt=2.5, description="no default")
    names: list[str] = Field(default_factory=list, description="a list")
    inner: Inner = Field(Inner(k=5), description="nested")


def test_rows_of_a_pydantic_model():
    rows = [tuple(dataclasses.astuple(r)) for r in pd.rows_of(Outer)]
    assert rows == [
        ("radius_m", "float or null", "`null`", ">= 0, finite", "a \\| b &lt;c&gt;"),
        ("mode", '"a" or "b"', '`"a"`', "", "which"),
        ("needed", "float", "required", "> 0, < 2.5", "no default"),
        ("names", "list[str]", "`[]`", "", "a list"),
        ("inner", "mapping (Inner)", '`{"k": 5}`', "", "nested"),
        ("inner.k", "int", "`3`", ">= 1", "neighbours"),
    ]


@dataclasses.dataclass(frozen=True)
class OldInner:
    k: int = 3


@dataclasses.dataclass(frozen=True)
class OldParams:
    """The form of the filters' parameters before pydantic: fields and defaults, no descriptions."""

    multiplier: float = 3.0
    max_range_m: float | None = None
    inner: OldInner = OldInner()


def test_rows_of_a_dataclass_and_of_a_signature():
    assert [tuple(dataclasses.astuple(r)) for r in pd.rows_of(OldParams)] == [
        ("multiplier", "float", "`3.0`", "", ""),
        ("max_range_m", "float or null", "`null`", "", ""),
        ("inner", "mapping (OldInner)", "`{}`", "", ""),
        ("inner.k", "int", "`3`", "", ""),
    ]

    def load(model_path: str | Path | None = None, threshold: float | None = None, *, seed: int = 0) -> None: ...

    assert [(r.name, r.type, r.default) for r in pd.rows_of(load)] == [
        ("model_path", "str or path or null", "`null`"), ("threshold", "float or null", "`null`"), ("seed", "int", "`0`"),
    ]


def test_filter_pages_follow_the_filters_parameter_classes():
    """Whatever form the filters' parameter classes have (dataclass or pydantic), every field is a row with its default."""
    from weather_filter.points.dror import DRORParams
    from weather_filter.points.dsor import DSORParams
    from weather_filter.points.echo import EchoParams
    from weather_filter.points.lior import LIORParams

    for method, cls in (("dror", DRORParams), ("dsor", DSORParams), ("lior", LIORParams), ("echo", EchoParams)):
        text = (REPO / f"src/weather_filter/docs/filters/{method}.md").read_text()
        defaults = cls()
        names = list(cls.model_fields) if hasattr(cls, "model_fields") else [f.name for f in dataclasses.fields(cls)]
        for name in names:
            value = getattr(defaults, name)
            if not dataclasses.is_dataclass(value) and not isinstance(value, pydantic.BaseModel):
                row = rf"^\| `{name}` \| [^|\n]+ \| {re.escape(pd.format_default(value))} \|"
                assert re.search(row, text, re.M), (method, name)
