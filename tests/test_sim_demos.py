"""Demo specs: families, YAML/JSON round trips, waypoint files and their errors."""

from pathlib import Path

import numpy as np
import pytest

from dcm.sim.demos import (
    DemoSpec,
    DemoSpecError,
    PathOutsideBowlError,
    WaypointFileError,
    load_waypoints_csv,
)
from dcm.sim.geometry import BowlSpec

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("family", ["spiral", "wavelike", "line"])
def test_design_families_stay_inside_and_approach_smoothly(family: str) -> None:
    spec = DemoSpec(family=family, press_m=0.012)
    path = spec.path(20.0)
    assert path.shape == (160, 3)  # 8 s at 20 Hz
    assert np.all(spec.bowl.contains(path[:, 0], path[:, 1]))
    # Approach: starts hover_m above the surface, reaches the pressing depth after approach_s, smoothly.
    assert path[0, 2] == pytest.approx(-spec.hover_m)
    assert np.allclose(path[20:, 2], 0.012)
    assert np.max(np.abs(np.diff(path[:, 2]))) < 0.003
    attractor = spec.attractor_path(20.0)
    surface = spec.bowl.height(path[:, 0], path[:, 1])
    assert np.all(attractor[20:, 2] < surface[20:])  # pushed below the surface


def test_spiral_direction_and_turns() -> None:
    def winding(direction: str) -> float:
        xy = DemoSpec(family="spiral", params={"direction": direction, "turns": 2.0}).path()[:, :2]
        return float(np.sum(np.diff(np.unwrap(np.arctan2(xy[:, 1], xy[:, 0])))) / (2 * np.pi))

    assert winding("ccw") == pytest.approx(2.0, abs=0.05)
    assert winding("cw") == pytest.approx(-2.0, abs=0.05)


def test_round_trip_yaml_json(tmp_path: Path) -> None:
    spec = DemoSpec(family="wavelike", params={"cycles": 3.0}, bowl=BowlSpec(shape="elliptic", aspect=0.8), name="w")
    for suffix in (".yaml", ".json"):
        spec.save(tmp_path / f"spec{suffix}")
        back = DemoSpec.load(tmp_path / f"spec{suffix}")
        assert back.to_dict() == spec.to_dict()
        assert np.array_equal(back.path(), spec.path())


def test_shipped_specs_load() -> None:
    for path in sorted((REPO / "data" / "demos").glob("*.yaml")) + sorted((REPO / "conf" / "demo").glob("*.yaml")):
        spec = DemoSpec.load(path)
        assert spec.horizon(20.0) == 160, path
    assert DemoSpec.from_dict({"family": "line", "bowl": "small"}).bowl.rim_radius_m == pytest.approx(0.10)


def test_waypoints_resampled_to_control_rate(tmp_path: Path) -> None:
    csv_path = tmp_path / "wp.csv"
    csv_path.write_text("t,x,y,press\n0,0.0,0.0,0.01\n1.0,0.05,0.0,0.01\n2.0,0.05,0.05,0.02\n")
    spec = DemoSpec(family="waypoints", waypoints=str(csv_path), approach_s=0.0)
    path = spec.path(20.0)
    assert path.shape == (41, 3)  # 0..2 s inclusive at 20 Hz
    assert np.allclose(path[10], [0.025, 0.0, 0.01])  # linear interpolation at t = 0.5 s
    assert np.allclose(path[-1], [0.05, 0.05, 0.02])
    table = load_waypoints_csv(REPO / "data" / "waypoints" / "example.csv")
    assert table.shape[1] == 4


@pytest.mark.parametrize(
    ("content", "pattern"),
    [
        ("t,x,y,press\n0,0,0,0.01\n1,nan,0,0.01\n", r"row 3, column x: value 'nan'"),
        ("t,x,y,press\n0,0,0,0.01\n", r"1 waypoint row\(s\)"),
        ("0,0,0,0.01\n1,0.01,0,0.01\n2,0.02,0,0.01\n", r"row 1: header"),
        ("t,x,y,press,speed\n0,0,0,0.01,1\n1,0.01,0,0.01,1\n", r"row 1: header"),
        ("t,x,y\n0,0,0\n1,0.01,0\n", r"row 1: header"),
        ("t,x,y,press\n0,0,0,0.01\n1,0.01,0\n", r"row 3: expected 4 values"),
        ("t,x,y,press\n0,0,0,0.01\n1,0.01,0,abc\n", r"row 3, column press: 'abc' is not a number"),
        ("t,x,y,press\n0,0,0,0.01\n0,0.01,0,0.01\n", r"row 3: t = 0 s does not increase"),
        ("t,x,y,press\n0,0,0,0.01\n1,0.5,0,0.01\n", r"row 3: \(x, y\) = \(0.5, 0\) m lies outside"),
    ],
    ids=["nan", "too-few-rows", "missing-header", "extra-column", "missing-column", "short-row", "text",
         "time-not-increasing", "outside-bowl"],
)
def test_bad_waypoint_files_name_file_row_value(tmp_path: Path, content: str, pattern: str) -> None:
    csv_path = tmp_path / "bad.csv"
    csv_path.write_text(content)
    with pytest.raises(WaypointFileError, match=pattern) as info:
        DemoSpec(family="waypoints", waypoints=str(csv_path)).path()
    assert str(csv_path) in str(info.value)


def test_design_path_leaving_the_bowl_is_rejected() -> None:
    spec = DemoSpec(family="spiral", params={"max_radius_m": 0.2}, bowl=BowlSpec(rim_radius_m=0.15))
    with pytest.raises(PathOutsideBowlError, match=r"leaves the bowl at step \d+ .* rim radius 0.15"):
        spec.path()


def test_bad_spec_fields_are_named(tmp_path: Path) -> None:
    with pytest.raises(DemoSpecError, match="family = 'zigzag'"):
        DemoSpec(family="zigzag")
    with pytest.raises(DemoSpecError, match=r"unknown spiral parameter\(s\) \['radius'\]"):
        DemoSpec(family="spiral", params={"radius": 0.1})
    with pytest.raises(DemoSpecError, match="press_m = 0.5"):
        DemoSpec(press_m=0.5)
    with pytest.raises(DemoSpecError, match="direction"):
        DemoSpec(params={"direction": "up"})
    bad = tmp_path / "bad.yaml"
    bad.write_text("family: line\nbowl: {shape: cone}\n")
    with pytest.raises(DemoSpecError, match=r"bad.yaml.*shape = 'cone'"):
        DemoSpec.load(bad)
    with pytest.raises(DemoSpecError, match="bowl preset 'huge' not found"):
        DemoSpec.from_dict({"family": "line", "bowl": "huge"})
