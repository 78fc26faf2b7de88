"""The path-family registry: the families it holds are the documented ones, an unknown family is refused naming
them, and a new family is one registration."""

import re
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import pytest

from dcm.sim.demos import FAMILIES, FAMILY_PARAMS, DemoSpec, DemoSpecError
from dcm.sim.paths import PATH_FAMILIES
from dcm.sim.paths.family import PathFamily

REPO = Path(__file__).resolve().parents[1]


def _documented_families() -> list[str]:
    """The family names the Demos section of docs/simulate.md lists: backticked names before a bullet's colon."""
    section = (REPO / "docs" / "simulate.md").read_text().split("\n## Demos\n")[1].split("\n## ")[0]
    bullets = re.findall(r"^- (.*)$", section, flags=re.M)
    return [name for bullet in bullets for name in re.findall(r"`(\w+)`", bullet.split(":")[0])]


def test_the_registered_families_are_the_documented_ones() -> None:
    assert _documented_families() == list(PATH_FAMILIES) == list(FAMILIES)
    assert FAMILY_PARAMS == {name: family.params for name, family in PATH_FAMILIES.items()}
    for name, family in PATH_FAMILIES.items():
        assert family.name == name
        assert family.__doc__, name  # a family says what its parameters mean
        spec = DemoSpec(family=name, waypoints=str(REPO / "data/waypoints/example.csv") if name == "waypoints" else None)
        assert spec.path(20.0).shape[1] == 3


def test_an_unknown_family_is_refused_naming_the_registered_ones() -> None:
    with pytest.raises(DemoSpecError) as info:
        DemoSpec.from_dict({"family": "zigzag"}, where="tune.demo")
    message = str(info.value)
    assert message.startswith("tune.demo: family = 'zigzag'; expected one of")
    assert all(repr(name) in message for name in PATH_FAMILIES), message
    with pytest.raises(DemoSpecError, match=r"family = \['spiral'\]; expected one of"):
        DemoSpec(family=["spiral"])  # type: ignore[arg-type]  # a YAML list, not a name
    with pytest.raises(DemoSpecError, match=r"curve_draws\(\) needs family 'curve' or 'paced_curve', not 'line'"):
        DemoSpec(family="line").curve_draws()
    with pytest.raises(DemoSpecError, match=r"speed_profile\(\) needs family 'paced_curve', not 'curve'"):
        DemoSpec(family="curve").speed_profile(np.zeros(3))


class _Circle(PathFamily):
    """A circle of ``radius_m`` around the centre, once round."""

    name = "circle"
    params: ClassVar[dict[str, Any]] = {"radius_m": 0.05}

    def check_params(self, spec: Any) -> None:
        if not 0.0 < self.param(spec, "radius_m") < spec.bowl.rim_radius_m:
            raise DemoSpecError(f"{spec.source}: circle params.radius_m = {self.param(spec, 'radius_m')!r} "
                                "must be inside the rim")

    def xy(self, spec: Any, t: np.ndarray, u: np.ndarray, wipe_s: float) -> np.ndarray:
        angle = 2.0 * np.pi * u
        return self.param(spec, "radius_m") * np.stack([np.cos(angle), np.sin(angle)], axis=1)


def test_a_new_family_is_one_registration(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setitem(PATH_FAMILIES, "circle", _Circle())
    spec = DemoSpec(family="circle", params={"radius_m": 0.04}, press_m=0.012)
    path = spec.path(20.0)
    assert path.shape == (160, 3)
    assert np.allclose(np.hypot(path[:, 0], path[:, 1]), 0.04)
    assert path[0, 2] == pytest.approx(-spec.hover_m) and np.allclose(path[20:, 2], 0.012)  # the shared approach
    spec.save(tmp_path / "circle.yaml")
    assert DemoSpec.load(tmp_path / "circle.yaml") == spec
    with pytest.raises(DemoSpecError, match=r"unknown circle parameter\(s\) \['turns'\]; known: \['radius_m'\]"):
        DemoSpec(family="circle", params={"turns": 2})
    with pytest.raises(DemoSpecError, match="circle params.radius_m = 0.3 must be inside the rim"):
        DemoSpec(family="circle", params={"radius_m": 0.3})
    with pytest.raises(DemoSpecError, match="'circle'"):
        DemoSpec(family="square")
