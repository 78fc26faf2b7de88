"""Demo specs: families, YAML/JSON round trips, waypoint files and their errors."""

import json
from pathlib import Path

import numpy as np
import pytest

from dcm.sim.demos import (
    CURVE_EXTENT,
    CURVE_HARMONICS,
    DemoSpec,
    DemoSpecError,
    PathOutsideBowlError,
    WaypointFileError,
    load_waypoints_csv,
)
from dcm.sim.geometry import BowlSpec

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("family", ["spiral", "wavelike", "line", "curve"])
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
        assert spec.horizon(20.0) == (240 if spec.lead else 160), path  # sim_contact's demos last 12 s
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


# -- the curve family --------------------------------------------------------------------------------------
CURVE = {"speed_mps": [0.02, 0.10], "press_range_m": [0.005, 0.02]}
BOWLS = sorted(p.stem for p in (REPO / "conf" / "bowl").glob("*.yaml"))


def _curve(seed: int, **params) -> DemoSpec:
    return DemoSpec(family="curve", params={"seed": seed, **CURVE, **params})


def test_curve_is_seeded_and_round_trips(tmp_path: Path) -> None:
    spec = _curve(7, harmonics=4)
    path = spec.path()
    assert np.array_equal(path, _curve(7, harmonics=4).path())  # same seed -> identical arrays
    assert not np.allclose(path, _curve(8, harmonics=4).path())
    back = DemoSpec.from_dict(json.loads(spec.to_json()))
    assert back == spec and np.array_equal(back.path(), path)
    spec.save(tmp_path / "curve.yaml")
    assert np.array_equal(DemoSpec.load(tmp_path / "curve.yaml").path(), path)
    # a tuple range is stored as a list, so the JSON round trip compares equal
    as_tuple = _curve(1, speed_mps=(0.03, 0.05))
    assert DemoSpec.from_dict(json.loads(as_tuple.to_json())).params["speed_mps"] == [0.03, 0.05]


@pytest.mark.parametrize("bowl", BOWLS)
def test_curve_stays_inside_the_rim_fraction(bowl: str) -> None:
    for seed in range(50):
        harmonics = CURVE_HARMONICS[0] + seed % CURVE_HARMONICS[1]
        extent = (0.5, 0.7, CURVE_EXTENT[1])[seed % 3]
        spec = DemoSpec.from_dict({"family": "curve", "bowl": bowl, "params": {
            "seed": seed, "harmonics": harmonics, "extent": extent, "speed_mps": [0.1, 0.3]}})
        xy = spec.path()[:, :2]
        a, b = spec.bowl.semi_axes_m
        rho = np.hypot(xy[:, 0] / a, xy[:, 1] / b)  # 1 on the rim, for elliptic bowls too
        assert rho.max() <= extent + 1e-6, (bowl, seed)
        assert np.all(spec.bowl.contains(xy[:, 0], xy[:, 1]))


def test_curve_speed_and_press_are_drawn_in_their_ranges() -> None:
    speeds, presses = [], []
    for seed in range(20):
        spec = _curve(seed)
        draws = spec.curve_draws()
        path = spec.path(20.0)
        wipe_s = spec.duration_s - spec.approach_s - 0.05
        step = np.linalg.norm(np.diff(path[:, :2], axis=0), axis=1)
        assert step.sum() / wipe_s == pytest.approx(draws["speed_mps"], rel=0.02)  # mean speed over the wipe
        assert np.allclose(path[20:, 2], draws["press_m"])
        # starts from rest: still during the approach, then a smooth start
        assert np.allclose(path[:21, :2], path[0, :2]) and step[20] < 0.2 * step.max()
        speeds.append(draws["speed_mps"])
        presses.append(draws["press_m"])
    assert 0.02 <= min(speeds) < max(speeds) <= 0.10 and 0.005 <= min(presses) < max(presses) <= 0.02
    assert np.allclose(_curve(0, press_range_m=None).path()[20:, 2], 0.01)  # no range: the spec's press_m
    # independent streams: a new speed range keeps the shape draw
    assert np.array_equal(_curve(3).curve_draws()["coeffs"], _curve(3, speed_mps=[0.05, 0.06]).curve_draws()["coeffs"])


@pytest.mark.parametrize(
    ("params", "pattern"),
    [
        ({"seed": -1}, r"params.seed = -1 must be an integer in \[0, 4294967295\]"),
        ({"seed": 1.5}, r"params.seed = 1.5 must be an integer"),
        ({"seed": True}, r"params.seed = True must be an integer"),
        ({"harmonics": 0}, r"params.harmonics = 0 must be an integer in \[1, 8\]"),
        ({"harmonics": 9}, r"params.harmonics = 9 must be an integer in \[1, 8\]"),
        ({"extent": 1.2}, r"params.extent = 1.2 must be a number in \[0.05, 0.95\] \(fraction of the rim radius\)"),
        ({"extent": "big"}, r"params.extent = 'big' must be a number in"),
        ({"speed_mps": [0.1, 0.05]}, r"params.speed_mps = \[0.1, 0.05\] must be \[low, high\] m/s with 0.005 <= low"),
        ({"speed_mps": [0.0, 0.1]}, r"params.speed_mps = \[0.0, 0.1\] must be"),
        ({"speed_mps": 0.05}, r"params.speed_mps = 0.05 must be \[low, high\]"),
        ({"press_range_m": [0.01, 0.2]}, r"params.press_range_m = \[0.01, 0.2\] must be \[low, high\] m with -0.05"),
        ({"press_range_m": [0.02, 0.01]}, r"params.press_range_m = \[0.02, 0.01\]"),
        ({"radius": 0.1}, r"unknown curve parameter\(s\) \['radius'\]"),
    ],
    ids=["seed-negative", "seed-float", "seed-bool", "harmonics-0", "harmonics-9", "extent-big", "extent-text",
         "speed-reversed", "speed-zero", "speed-scalar", "press-deep", "press-reversed", "unknown"],
)
def test_bad_curve_parameters_are_named(params: dict, pattern: str) -> None:
    with pytest.raises(DemoSpecError, match=pattern):
        DemoSpec(family="curve", params=params)
    assert issubclass(DemoSpecError, ValueError)


def test_short_curve_demo_records_on_the_tool() -> None:
    from dcm.sim.rollout import Simulator

    spec = DemoSpec(family="curve", params={"seed": 5, **CURVE}, duration_s=2.0, approach_s=0.4,
                    bowl=BowlSpec(rim_radius_m=0.12, depth_m=0.03, hfield_res=64))
    demo = Simulator(embodiment="tool", bowl=spec.bowl, control_hz=20.0, seed=0).record_demo(spec)
    assert demo.x_demo.shape == demo.force_demo.shape == (40, 6)
    assert np.all(np.isfinite(demo.force_demo)) and demo.contact[15:].all()
    assert np.abs(demo.x_demo[15:, :2] - spec.path()[15:, :2]).max() < 0.01  # follows the curve
    assert demo.force_demo[15:, 2].mean() > 1.0  # pressing down


# -- the leading demonstrator ------------------------------------------------------------------------------
def test_lead_is_serialised_only_when_set_and_checked() -> None:
    plain = DemoSpec(family="spiral")
    assert "lead" not in plain.to_dict()  # specs from before the field keep their JSON (and their demo seeds)
    led = DemoSpec.from_dict({**plain.to_dict(), "lead": True})
    assert led.lead and led.to_dict()["lead"] is True and DemoSpec.from_dict(led.to_dict()) == led
    with pytest.raises(DemoSpecError, match="lead = 'yes'"):
        DemoSpec(lead="yes")


def test_leading_demonstrator_follows_the_path_closer_on_the_panda() -> None:
    """A fast spiral on a small bowl: the plain demo controller trails the path by centimetres; leading by the
    impedance lag keeps the tool within millimetres of it."""
    from dcm.sim.rollout import Simulator

    bowl = BowlSpec(rim_radius_m=0.10, depth_m=0.05, hfield_res=64)
    sim = Simulator(embodiment="panda", bowl=bowl, control_hz=20.0, seed=0)
    trail = {}
    for lead in (False, True):
        spec = DemoSpec(family="spiral", params={"turns": 2.5}, press_m=0.01, duration_s=6.0, bowl=bowl, lead=lead)
        demo = sim.record_demo(spec)
        trail[lead] = np.linalg.norm(demo.x_demo[30:, :2] - spec.path(20.0)[30:, :2], axis=1).mean()
    assert trail[False] > 0.015 and trail[True] < 0.3 * trail[False]


# -- a waypoint file is a family of its own, with its own timing --------------------------------------------
def _waypoint_file(tmp_path: Path, span_s: float = 10.0, name: str = "path.csv") -> Path:
    path = tmp_path / name
    path.write_text(f"t,x,y,press\n0,0.0,0.0,0.01\n{span_s / 2:g},0.03,0.0,0.01\n{span_s:g},0.03,0.03,0.01\n")
    return path


def test_a_waypoint_file_with_another_family_is_refused_naming_both(tmp_path: Path) -> None:
    """`+demo.waypoints=my.csv` without `demo=waypoints` would wipe the preset's stroke, not the file."""
    csv = _waypoint_file(tmp_path)
    with pytest.raises(DemoSpecError) as info:
        DemoSpec.from_dict({"family": "wavelike", "waypoints": str(csv)}, where="tune.demo")
    message = str(info.value)
    assert "family = 'wavelike'" in message and str(csv) in message and "family 'waypoints'" in message
    assert "\n" not in message


def test_a_waypoint_demo_records_the_file_s_own_duration(tmp_path: Path) -> None:
    csv = _waypoint_file(tmp_path, 10.0)
    spec = DemoSpec.from_dict({"family": "waypoints", "waypoints": str(csv)})
    assert spec.duration_s == 10.0 and spec.to_dict()["duration_s"] == 10.0  # what results.json records
    assert spec.to_dict()["press_m"] is None  # the file's press column sets the depth
    assert DemoSpec.from_dict(spec.to_dict()) == spec  # round trip
    for key, value, pattern in [
        ("duration_s", 12.0, rf"duration_s = 12 s, but the waypoint file {csv} spans 10 s"),
        ("duration_s", 8.0, rf"duration_s = 8 s, but the waypoint file {csv} spans 10 s"),
        ("press_m", 0.02, r"press_m = 0.02 does not apply to a waypoint file"),
    ]:
        with pytest.raises(DemoSpecError, match=pattern) as info:
            DemoSpec.from_dict({"family": "waypoints", "waypoints": str(csv), key: value}, where="tune.demo")
        assert str(info.value).startswith("tune.demo: ") and "(the demo's length)" not in str(info.value)
    assert DemoSpec(family="spiral").duration_s == 8.0 and DemoSpec(family="spiral").press_m == 0.01


def test_a_leading_demonstrator_applies_to_a_waypoint_demo(tmp_path: Path) -> None:
    from dcm.sim.rollout import Simulator

    csv = _waypoint_file(tmp_path, 2.0)
    plain = DemoSpec.from_dict({"family": "waypoints", "waypoints": str(csv), "approach_s": 0.4})
    led = DemoSpec.from_dict({**plain.to_dict(), "lead": True})
    assert led.to_dict()["lead"] is True
    sim = Simulator(embodiment="tool", bowl=plain.bowl, control_hz=20.0, seed=0)
    assert not np.allclose(sim.record_demo(plain).x_demo, sim.record_demo(led).x_demo)


def test_retiming_a_waypoint_file_as_the_recording_warning_advises_silences_it(tmp_path: Path) -> None:
    """A 10 s file against a model of 12 s demos (240 steps at 20 Hz): the advice names the span that gives
    240 steps, and a file retimed to exactly that span is recorded as the model's demos were."""
    import re

    from dcm.tuning.diagnostics import recording_mismatch

    contact = REPO / "models/dcm_diverse_contact.ckpt"  # 12 s demos with a leading demonstrator

    def file_spanning(span_s: float) -> DemoSpec:
        t = np.linspace(0.0, span_s, 11)
        csv = tmp_path / "path.csv"
        csv.write_text("t,x,y,press\n" + "".join(f"{ti:.6g},{0.05 * np.cos(ti):.5f},{0.05 * np.sin(ti):.5f},0.008\n"
                                                 for ti in t))
        return DemoSpec(family="waypoints", waypoints=str(csv), lead=True)

    message = recording_mismatch(contact, file_spanning(10.0))
    advised = re.search(r"retime \S+ to span ([0-9.]+) s \(240 steps at 20 Hz", message)
    assert advised, message
    retimed = file_spanning(float(advised.group(1)))
    assert retimed.horizon(20.0) == 240
    assert recording_mismatch(contact, retimed) is None
