"""Bowl geometry: analytic surface, presets, and agreement with the compiled MuJoCo heightfield."""

import glob

import mujoco
import numpy as np
import pytest

from dcm.sim.domain import DomainSpec, DomainSpecError
from dcm.sim.geometry import BowlSpec, BowlSpecError
from dcm.sim.scene import BOWL_GEOM, add_bowl

SHAPES = [
    BowlSpec(shape="spherical_cap", rim_radius_m=0.15, depth_m=0.05),
    BowlSpec(shape="flat", rim_radius_m=0.15, depth_m=0.0),
    BowlSpec(shape="elliptic", rim_radius_m=0.15, depth_m=0.04, aspect=0.7),
]


@pytest.mark.parametrize("bowl", SHAPES, ids=lambda b: b.shape)
def test_surface_origin_rim_and_normal(bowl: BowlSpec) -> None:
    assert bowl.height(0.0, 0.0) == pytest.approx(0.0, abs=1e-12)
    assert np.allclose(bowl.normal(0.0, 0.0), [0, 0, 1])
    a, b = bowl.semi_axes_m
    assert bowl.height(a, 0.0) == pytest.approx(bowl.rim_height_m, abs=1e-9)
    assert bowl.height(0.0, b) == pytest.approx(bowl.rim_height_m, abs=1e-9)
    assert bowl.contains(0.5 * a, 0.5 * b) and not bowl.contains(1.01 * a, 0.0)
    # The normal is the normalised (-dz/dx, -dz/dy, 1): compare with central differences.
    rng = np.random.default_rng(0)
    xy = rng.uniform(-0.6, 0.6, size=(50, 2)) * [a, b]
    eps = 1e-6
    gx = (bowl.height(xy[:, 0] + eps, xy[:, 1]) - bowl.height(xy[:, 0] - eps, xy[:, 1])) / (2 * eps)
    gy = (bowl.height(xy[:, 0], xy[:, 1] + eps) - bowl.height(xy[:, 0], xy[:, 1] - eps)) / (2 * eps)
    expected = np.stack([-gx, -gy, np.ones_like(gx)], axis=1)
    expected /= np.linalg.norm(expected, axis=1, keepdims=True)
    assert np.allclose(bowl.normal(xy[:, 0], xy[:, 1]), expected, atol=1e-6)


@pytest.mark.parametrize("bowl", SHAPES, ids=lambda b: b.shape)
def test_heightfield_matches_analytic_surface(bowl: BowlSpec) -> None:
    """Rays cast down onto the compiled heightfield hit the analytic height.

    The heightfield interpolates the surface linearly between grid nodes ~4 mm apart; for the 0.25 m
    sphere radius of the cap that chord error is below (4 mm)^2 / (8 * 0.25 m) = 8 um, and the elevation
    is stored as float32, so 0.1 mm is a generous bound. Points stay inside 95% of the rim: across the
    kink where the cap meets the flat lip the interpolation error is slope x cell/2 (~0.6 mm).
    """
    spec = mujoco.MjSpec()
    add_bowl(spec, bowl, DomainSpec())
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    geom_id = np.zeros(1, dtype=np.int32)
    a, b = bowl.semi_axes_m
    rng = np.random.default_rng(1)
    radius, angle = 0.95 * np.sqrt(rng.uniform(0, 1, 40)), rng.uniform(0, 2 * np.pi, 40)
    for x, y in zip(a * radius * np.cos(angle), b * radius * np.sin(angle)):
        dist = mujoco.mj_ray(model, data, np.array([x, y, 1.0]), np.array([0.0, 0.0, -1.0]), None, 1, -1, geom_id)
        assert model.geom(int(geom_id[0])).name == BOWL_GEOM
        assert 1.0 - dist == pytest.approx(bowl.height(x, y), abs=1e-4)


def test_presets_load_and_round_trip() -> None:
    files = sorted(glob.glob("conf/bowl/*.yaml"))
    assert {BowlSpec.load(f).shape for f in files} == {"spherical_cap", "flat", "elliptic"}
    for f in files:
        bowl = BowlSpec.load(f)
        assert BowlSpec.from_dict(bowl.to_dict()) == bowl
    for name in ("nominal", "realistic", "replaced_bowl"):
        dom = DomainSpec.load(f"conf/domain/{name}.yaml")
        assert dom == DomainSpec.preset(name)
        assert DomainSpec.from_dict(dom.to_dict()) == dom


def test_bad_bowl_and_domain_values_are_named() -> None:
    with pytest.raises(BowlSpecError, match="shape"):
        BowlSpec(shape="saddle_bowl")
    with pytest.raises(BowlSpecError, match="depth_m"):
        BowlSpec(shape="spherical_cap", rim_radius_m=0.1, depth_m=0.2)
    with pytest.raises(BowlSpecError, match="colour"):
        BowlSpec.from_dict({"shape": "flat", "colour": "red"})
    with pytest.raises(DomainSpecError, match="friction_scale"):
        DomainSpec(friction_scale=-1.0)
    with pytest.raises(DomainSpecError, match="unknown domain preset"):
        DomainSpec.preset("real")
