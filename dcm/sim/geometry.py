"""Parametric concave surfaces the tool wipes, with analytic height and normal for demos and checks.

All coordinates are in the bowl frame: world axes, z up, origin at the lowest point of the surface at the
bowl's centre. The same functions feed the MuJoCo heightfield (``scene.add_bowl``) and the demo designer,
so a demo path and the collision surface agree up to the heightfield's grid resolution.

Shapes:

* ``spherical_cap``: a cap of a sphere with rim radius ``rim_radius_m`` and depth ``depth_m``.
* ``flat``: a plate at z = 0; ``rim_radius_m`` is the radius of the usable disc.
* ``elliptic``: an elliptic paraboloid ``z = depth (x²/a² + y²/b²)``, ``a = rim_radius_m``, ``b = aspect·a``.

Outside the rim the surface continues as a flat lip at the rim height, so a tool that overshoots still
finds ground instead of falling off the heightfield.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, ClassVar

import numpy as np

from dcm.sim.spec_io import SpecIO

SHAPES = ("spherical_cap", "flat", "elliptic")


class BowlSpecError(ValueError):
    """An invalid bowl description (names the field and value)."""


@dataclass
class BowlSpec(SpecIO):
    """A bowl (or plate) and its contact properties.

    ``solref``/``solimp`` follow MuJoCo's meaning. The defaults are deliberately soft: with MuJoCo's stiff
    default a sliding sphere chatters on the heightfield facets and the force spikes.
    """

    spec_kind: ClassVar[str] = "bowl"
    spec_error: ClassVar[type[ValueError]] = BowlSpecError

    shape: str = "spherical_cap"
    rim_radius_m: float = 0.15
    depth_m: float = 0.05
    aspect: float = 1.0
    friction: float = 0.3
    solref: tuple[float, float] = (0.02, 1.0)
    solimp: tuple[float, float, float, float, float] = (0.0, 0.95, 0.005, 0.5, 2.0)
    hfield_res: int = 96
    lip_m: float = 0.04
    name: str = ""

    def __post_init__(self) -> None:
        self.solref = tuple(float(v) for v in self.solref)  # type: ignore[assignment]
        self.solimp = tuple(float(v) for v in self.solimp)  # type: ignore[assignment]
        self.validate()

    # -- validation / io -------------------------------------------------------------------------
    def validate(self) -> None:
        """Raise ``BowlSpecError`` naming the first bad field."""
        if self.shape not in SHAPES:
            raise BowlSpecError(f"bowl.shape = {self.shape!r}; expected one of {SHAPES}")
        checks = {
            "rim_radius_m": (self.rim_radius_m, 0.02, 1.0),
            "depth_m": (self.depth_m, 0.0, 0.5),
            "aspect": (self.aspect, 0.2, 5.0),
            "friction": (self.friction, 0.0, 2.0),
            "hfield_res": (self.hfield_res, 16, 1024),
            "lip_m": (self.lip_m, 0.0, 0.5),
        }
        for key, (value, low, high) in checks.items():
            if not np.isfinite(value) or not (low <= value <= high):
                raise BowlSpecError(f"bowl.{key} = {value!r} is outside [{low}, {high}]")
        if self.shape != "flat" and self.depth_m <= 0:
            raise BowlSpecError(f"bowl.depth_m = {self.depth_m!r} must be > 0 for shape {self.shape!r}")
        if self.shape == "spherical_cap" and self.depth_m > self.rim_radius_m:
            raise BowlSpecError(
                f"bowl.depth_m = {self.depth_m} exceeds rim_radius_m = {self.rim_radius_m}: "
                "a spherical cap deeper than a hemisphere is not a heightfield"
            )
        if len(self.solref) != 2 or len(self.solimp) != 5:
            raise BowlSpecError(f"bowl.solref needs 2 and bowl.solimp 5 numbers; got {self.solref}, {self.solimp}")

    def to_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["solref"] = list(self.solref)
        out["solimp"] = list(self.solimp)
        return out

    # -- analytic surface ------------------------------------------------------------------------
    @property
    def semi_axes_m(self) -> tuple[float, float]:
        """Half extents (x, y) of the usable region."""
        if self.shape == "elliptic":
            return self.rim_radius_m, self.rim_radius_m * self.aspect
        return self.rim_radius_m, self.rim_radius_m

    @property
    def sphere_radius_m(self) -> float:
        """Radius of the sphere a spherical cap is cut from (r² + d²) / 2d."""
        return (self.rim_radius_m**2 + self.depth_m**2) / (2.0 * self.depth_m)

    @property
    def rim_height_m(self) -> float:
        return 0.0 if self.shape == "flat" else self.depth_m

    def _rho2(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Normalised squared radius: 1 on the rim."""
        a, b = self.semi_axes_m
        return (x / a) ** 2 + (y / b) ** 2

    def contains(self, x: Any, y: Any) -> Any:
        """True where (x, y) [m] lies inside the rim (the usable surface)."""
        inside = self._rho2(np.asarray(x, float), np.asarray(y, float)) <= 1.0 + 1e-9
        return bool(inside) if np.ndim(inside) == 0 else inside

    def height(self, x: Any, y: Any) -> Any:
        """Surface height z [m] at (x, y) [m]; the lip outside the rim is at the rim height."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        if self.shape == "flat":
            z = np.zeros(np.broadcast(x, y).shape)
        elif self.shape == "spherical_cap":
            r2 = np.minimum(x**2 + y**2, self.rim_radius_m**2)
            big_r = self.sphere_radius_m
            z = big_r - np.sqrt(big_r**2 - r2)
        else:
            z = self.depth_m * np.minimum(self._rho2(x, y), 1.0)
        return float(z) if z.ndim == 0 else z

    def height_scalar(self, x: float, y: float) -> float:
        """``height`` for one point without numpy overhead (called every control step)."""
        if self.shape == "flat":
            return 0.0
        if self.shape == "spherical_cap":
            r2 = min(x * x + y * y, self.rim_radius_m**2)
            big_r = self.sphere_radius_m
            return big_r - math.sqrt(big_r * big_r - r2)
        a, b = self.semi_axes_m
        return self.depth_m * min((x / a) ** 2 + (y / b) ** 2, 1.0)

    def gradient(self, x: Any, y: Any) -> tuple[Any, Any]:
        """(dz/dx, dz/dy) of the surface; zero on the lip."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        shape = np.broadcast(x, y).shape
        inside = self._rho2(x, y) <= 1.0
        if self.shape == "flat":
            gx, gy = np.zeros(shape), np.zeros(shape)
        elif self.shape == "spherical_cap":
            big_r = self.sphere_radius_m
            root = np.sqrt(np.maximum(big_r**2 - (x**2 + y**2), 1e-12))
            gx, gy = np.where(inside, x / root, 0.0), np.where(inside, y / root, 0.0)
        else:
            a, b = self.semi_axes_m
            gx = np.where(inside, 2 * self.depth_m * x / a**2, 0.0)
            gy = np.where(inside, 2 * self.depth_m * y / b**2, 0.0)
        gx, gy = np.broadcast_to(gx, shape), np.broadcast_to(gy, shape)
        if gx.ndim == 0:
            return float(gx), float(gy)
        return gx, gy

    def normal(self, x: Any, y: Any) -> np.ndarray:
        """Unit surface normal (pointing up, out of the material) at (x, y); shape (..., 3)."""
        gx, gy = self.gradient(x, y)
        n = np.stack(np.broadcast_arrays(-np.asarray(gx), -np.asarray(gy), np.ones(np.shape(gx))), axis=-1)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)

    # -- heightfield -----------------------------------------------------------------------------
    @property
    def half_extent_m(self) -> tuple[float, float]:
        """Half size (x, y) of the heightfield: the usable region plus the lip."""
        a, b = self.semi_axes_m
        return a + self.lip_m, b + self.lip_m

    def heightfield(self) -> tuple[np.ndarray, float]:
        """Elevation grid (nrow=y, ncol=x) in [0, 1] and its vertical scale [m] for a MuJoCo hfield.

        Row ``i`` is y from -half to +half, column ``j`` x likewise (MuJoCo's layout).
        """
        hx, hy = self.half_extent_m
        n = int(self.hfield_res)
        xs = np.linspace(-hx, hx, n)
        ys = np.linspace(-hy, hy, n)
        gx, gy = np.meshgrid(xs, ys)
        z = self.height(gx, gy)
        top = max(self.rim_height_m, 1e-3)
        return np.clip(z / top, 0.0, 1.0), top
