"""How a dataset's demos were recorded: their duration and whether the demonstrator led the tool.

A predictor meets a new skill's demo through F_demo and x_demo, so it should see that demo recorded as its
training demos were: ``tune.py`` warns and ``bench/acceptance.py`` pairs files on this.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, NamedTuple


class Recording(NamedTuple):
    duration_s: float
    lead: bool

    def describe(self) -> str:
        return f"{self.duration_s:g} s demos {'with' if self.lead else 'without'} a leading demonstrator"


def recording(dataset_config: Mapping[str, Any]) -> Recording:
    """The recording of a dataset preset (``conf/dataset/*.yaml``; DemoSpec's defaults where it says nothing)."""
    return Recording(float(dataset_config.get("duration_s", 8.0)), bool(dataset_config.get("demo_lead", False)))


def preset_recording(name: str | None) -> Recording | None:
    """The recording of the preset ``conf/dataset/<name>.yaml``; None when no preset has that name."""
    from dcm.data.generate import CONF_DIR, compose_config

    if not name or not (CONF_DIR / "dataset" / f"{name}.yaml").is_file():
        return None
    return recording(compose_config(name).dataset)


def file_recording(path: str | Path) -> Recording:
    """The recording of a generated dataset file, from the generating config in its root attributes."""
    import h5py
    import yaml

    with h5py.File(path, "r") as f:
        return recording(yaml.safe_load(f.attrs["config"])["dataset"])
