"""How a dataset's demos were recorded: their duration, whether the demonstrator led the tool, and the bowl grid.

A predictor meets a new skill's demo through F_demo and x_demo, so it should see that demo recorded as its
training demos were: ``tune.py`` warns and the acceptance study pairs files on this. The bowl grid is part of
it because MuJoCo wipes a heightfield of flat facets: on a coarse grid a fast stroke's force jumps at the facet
edges, which a predictor trained on a converged grid never saw (studies/record.md, "The bowl's heightfield
grid").
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any, NamedTuple


class Recording(NamedTuple):
    duration_s: float
    lead: bool
    bowl_grid: int | None = None  # the preset's bowl.hfield_res; None: each bowl keeps its own
    hover_m: float | None = None  # the preset's demo_hover_m; None: DemoSpec's default

    def describe(self) -> str:
        grid = "" if self.bowl_grid is None else f" on a {self.bowl_grid} x {self.bowl_grid} bowl grid"
        hover = "" if self.hover_m is None else f", approaching from {self.hover_m:g} m above the bowl"
        return f"{self.duration_s:g} s demos {'with' if self.lead else 'without'} a leading demonstrator{grid}{hover}"


def recording(dataset_config: Mapping[str, Any]) -> Recording:
    """The recording of a dataset preset (``conf/dataset/*.yaml``; DemoSpec's defaults where it says nothing)."""
    grid = (dataset_config.get("bowl") or {}).get("hfield_res")
    hover = dataset_config.get("demo_hover_m")
    return Recording(float(dataset_config.get("duration_s", 8.0)), bool(dataset_config.get("demo_lead", False)),
                     None if grid is None else int(grid), None if hover is None else float(hover))


def stored_recording(attrs: Mapping[str, Any], path: str | Path = "<dataset>") -> dict[str, Any] | None:
    """The recording of a generated dataset, from its root attributes (as :func:`dcm.data.schema.read_root_attrs`
    gives them), as a plain dict a model card or a reference's fit record stores; None for a file that records no
    generating preset (imported robot logs). A predictor carries it so that a check finds it whichever preset,
    product or research, made the data."""
    from dcm.data.schema import read_config

    dataset = read_config(attrs, path).get("dataset")
    return recording(dataset)._asdict() if dataset else None


def preset_recording(name: str | None) -> Recording | None:
    """The recording of the preset ``conf/dataset/<name>.yaml``; None when no preset has that name."""
    from dcm.configs import CONF_DIR
    from dcm.data.presets import compose_config

    if not name or not (CONF_DIR / "dataset" / f"{name}.yaml").is_file():
        return None
    return recording(compose_config(name).dataset)


def file_recording(path: str | Path) -> Recording:
    """The recording of a generated dataset file, from the generating config in its root attributes."""
    from dcm.data.schema import read_config, read_root_attrs

    return recording(read_config(read_root_attrs(path), path).get("dataset") or {})
