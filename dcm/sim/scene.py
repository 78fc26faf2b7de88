"""Adds a bowl heightfield to any ``mujoco.MjSpec`` so both embodiments share one surface definition.

MuJoCo collides only convex meshes; a concave bowl is therefore a heightfield built from the analytic
surface in ``geometry.BowlSpec``. The bowl geom gets a higher contact ``priority`` than anything else, so
its friction and softness (scaled by the domain) decide every tool–bowl contact.
"""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import numpy as np

from dcm.sim.domain import DomainSpec
from dcm.sim.geometry import BowlSpec

BOWL_GEOM = "bowl"
BOWL_HFIELD = "bowl_hfield"
# Thickness of the heightfield's base box below the lowest point [m]; thick enough that a pressing tool
# never tunnels through.
BASE_THICKNESS_M = 0.02


def bowl_contact_params(bowl: BowlSpec, domain: DomainSpec) -> dict[str, list[float]]:
    """Friction, solref and solimp of the bowl geom after the domain's perturbations."""
    solref = [bowl.solref[0] * domain.solref_timeconst_scale, bowl.solref[1]]
    return {
        # sliding, torsional, rolling friction; only sliding matters for a sphere tip with condim 3.
        "friction": [bowl.friction * domain.friction_scale, 0.005, 0.0001],
        "solref": solref,
        "solimp": list(bowl.solimp),
    }


def add_bowl(
    spec: mujoco.MjSpec,
    bowl: BowlSpec,
    domain: DomainSpec,
    origin_world: Sequence[float] = (0.0, 0.0, 0.0),
) -> mujoco.MjsGeom:
    """Add the bowl heightfield to ``spec`` with its lowest surface point at ``origin_world`` [m].

    The bowl frame is the world frame translated to ``origin_world``; embodiments convert poses with it.
    Returns the geom so callers may tweak visuals.
    """
    elevation, top_m = bowl.heightfield()
    hx, hy = bowl.half_extent_m
    hfield = spec.add_hfield()
    hfield.name = BOWL_HFIELD
    hfield.size = [hx, hy, top_m, BASE_THICKNESS_M]
    hfield.nrow = elevation.shape[0]
    hfield.ncol = elevation.shape[1]
    hfield.userdata = elevation.astype(np.float32).ravel().tolist()

    params = bowl_contact_params(bowl, domain)
    geom = spec.worldbody.add_geom()
    geom.name = BOWL_GEOM
    geom.type = mujoco.mjtGeom.mjGEOM_HFIELD
    geom.hfieldname = BOWL_HFIELD
    geom.pos = np.asarray(origin_world, dtype=np.float64)
    geom.friction = params["friction"]
    geom.solref = params["solref"]
    geom.solimp = params["solimp"]
    geom.priority = 2
    geom.condim = 3
    geom.rgba = [0.75, 0.78, 0.85, 1.0]
    return geom
