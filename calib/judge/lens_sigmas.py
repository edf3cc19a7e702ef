"""The intrinsics a rig gives beyond the focal length (principal point, distortion): the sigma each
is assumed to have where rig.json gives none, measured on real lenses, and how a camera's
observations move when one is off by it. :mod:`wandcal.calib.judge.intrinsic_limits` turns that
movement into the camera's centre's (the honest sigma) and names the parameters that limit it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from wandcal.calib.geometry import distort_points, undistort_points

# the given intrinsics beyond the focal length (OpenCV's names; a fisheye lens has no p1, p2), each
# with its sigma where rig.json gives none. Measured on Brown's two calibrations of the same four
# cameras on consecutive days, each day with its own lens profile (a parameter's differences
# between the days, RMS over sqrt(2)), and on the published eWand session (its yaml files against
# what its own tracks give); docs/decisions/0070-every-given-intrinsic-in-the-honest-sigma.md.
# Four cameras a session: each figure is known to about a third of itself
LENS_PARAMETERS = {"pinhole": ("cx", "cy", "k1", "k2", "p1", "p2"), "fisheye": ("cx", "cy", "k1", "k2")}
DIST_INDEX = {"k1": 0, "k2": 1, "p1": 2, "p2": 3}
# the principal point's sigma, a share of the image's width: RMS over 16 axes of Brown's day-to-day
# differences over sqrt(2) (0.28%) and of the published eWand session's yaml principal points
# against those its own tracks give with --refine-intrinsics focal,principal,k1 (1.13%: 2-22 px,
# each to 1.1-1.6 px)
DEFAULT_PRINCIPAL_WIDTH_STD = 0.0082
# a principal point given at the image's centre (within NOMINAL_PX) is nominal, not calibrated: its
# sigma is how far real principal points lie from the centre, RMS over 16 axes of the eight
# calibrated lenses we have (Brown 1's four, MultiCamSelfCal's four): 2.1% of the width
DEFAULT_NOMINAL_PRINCIPAL_WIDTH_STD = 0.021
NOMINAL_PX = 0.5
# a radial term's sigma as the share of the radius it moves a point at the image's corner
# (k_n r_c^2n, r_c the corner's normalised radius; Brown: k1 1.66%, k2 2.40%): a share carries
# over to lenses of other fields of view, a coefficient would not
DEFAULT_RADIAL_CORNER_STD = {"k1": 0.0166, "k2": 0.0240}
# p1, p2 (Brown's profiles give none): the RMS of the eight calibrated p's of MultiCamSelfCal's four
# lenses, what a rig.json that gives 0 is off by on such a lens
DEFAULT_TANGENTIAL_STD = 0.0007
# the data determine a parameter when they would give it to this share of its sigma: the focal
# length's DETERMINED_REL_STD at its default sigma (wandcal.calib.judge.intrinsic_limits: 0.5% of 2%)
DETERMINED_SHARE = 0.25
WHY = {"nominal": " for a principal point given at the image's centre"}  # a limit message's words on its sigma
# the parameters --refine-intrinsics refines (wandcal.calib.solve.reprojection.INTRINSICS)
REFINABLE = {"cx": "principal", "cy": "principal", "k1": "k1"}
WORDS = {"cx": "principal point's x (cx)", "cy": "principal point's y (cy)", "k1": "radial distortion k1",
         "k2": "radial distortion k2", "p1": "tangential distortion p1", "p2": "tangential distortion p2"}

@dataclass(frozen=True)
class LensLimit:
    """One camera's centre against one given intrinsic beyond the focal length (``name`` of
    :data:`LENS_PARAMETERS`). shift_m_per_sigma: (3,) the centre's change, metres (or the rig's
    units), for the parameter off by its ``sigma`` (pixels for cx, cy; unitless else);
    along_axis_m_per_sigma: its part along the optical axis; data_std: the parameter's standard
    error from the camera's own residuals, in units of ``sigma`` (under :data:`DETERMINED_SHARE`:
    the data determine it)."""

    name: str
    shift_m_per_sigma: np.ndarray
    along_axis_m_per_sigma: float
    sigma: float
    data_std: float
    source: str = "default"  # "nominal" for a principal point given at the image's centre

    @property
    def std(self) -> float:
        """The centre's sigma from this parameter alone (3D RMS), metres."""
        return float(np.linalg.norm(self.shift_m_per_sigma))

    @property
    def determined(self) -> bool:
        return bool(np.isfinite(self.data_std) and self.data_std < DETERMINED_SHARE)


def lens_sigmas(cam) -> dict[str, float]:
    """Camera ``cam``'s assumed sigma of each of :data:`LENS_PARAMETERS` (pixels for cx, cy)."""
    cx, cy = cam.K[0, 2], cam.K[1, 2]
    corner = float(np.hypot(max(cx, cam.width - cx) / cam.K[0, 0], max(cy, cam.height - cy) / cam.K[1, 1]))
    if cam.model == "fisheye":
        corner = float(np.arctan(corner))  # its radial terms are on the ray's angle
    share = DEFAULT_NOMINAL_PRINCIPAL_WIDTH_STD if nominal_principal(cam) else DEFAULT_PRINCIPAL_WIDTH_STD
    out = {"cx": share * cam.width, "cy": share * cam.width}
    for name in LENS_PARAMETERS[cam.model][2:]:
        out[name] = (DEFAULT_RADIAL_CORNER_STD[name] / corner ** (2 * (DIST_INDEX[name] + 1))
                     if name in DEFAULT_RADIAL_CORNER_STD else DEFAULT_TANGENTIAL_STD)
    return out


def nominal_principal(cam) -> bool:
    """The camera's principal point is the image's centre (:data:`NOMINAL_PX`): nominal, not calibrated."""
    return bool(abs(cam.K[0, 2] - cam.width / 2) <= NOMINAL_PX and abs(cam.K[1, 2] - cam.height / 2) <= NOMINAL_PX)


def _perturbed(cam, name: str, delta: float):
    K, dist = cam.K.copy(), cam.dist.copy()
    if name == "cx":
        K[0, 2] += delta
    elif name == "cy":
        K[1, 2] += delta
    else:
        dist[DIST_INDEX[name]] += delta
    return replace(cam, K=K, dist=dist)


def lens_columns(cam, xy: np.ndarray, sigmas: dict[str, float]) -> dict[str, np.ndarray]:
    """(K, 2) how each observation's normalised coordinates xy (K, 2) move when the parameter
    ``name`` of ``sigmas`` is off by its sigma, the pixels held. A pinhole lens to first order
    (:func:`_pinhole_columns`); a fisheye's by the same pixels undistorted with the parameter at
    plus and minus its sigma, half the difference."""
    if cam.model == "pinhole":
        return _pinhole_columns(cam, xy, sigmas)
    uv = distort_points(cam, xy)
    return {name: 0.5 * (undistort_points(_perturbed(cam, name, s), uv) - undistort_points(_perturbed(cam, name, -s), uv))
            for name, s in sigmas.items()}


def _pinhole_columns(cam, xy: np.ndarray, sigmas: dict[str, float]) -> dict[str, np.ndarray]:
    """:func:`lens_columns` of OpenCV's pinhole model ``x_d = D(x; k1, k2, p1, p2, k3)``, pixels
    ``K x_d``: with the pixels held, a parameter ``q`` off by ``s`` moves x by ``-J^-1 dD/dq s``
    (J: dD/dx, (K, 2, 2)), and cx, cy move x_d by ``-K2^-1 e s`` (K2: K's upper 2 x 2)."""
    k1, k2, p1, p2, k3 = cam.dist
    x, y = xy[:, 0], xy[:, 1]
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    g = 2 * k1 + r2 * (4 * k2 + 6 * k3 * r2)  # d(radial)/dx = g x, d(radial)/dy = g y
    a = radial + g * x * x + 2 * p1 * y + 6 * p2 * x  # J = [[a, b], [b, d]], symmetric
    b = g * x * y + 2 * p1 * x + 2 * p2 * y
    d = radial + g * y * y + 6 * p1 * y + 2 * p2 * x
    det = a * d - b * b
    dD = {"k1": np.stack([x * r2, y * r2], axis=1), "k2": np.stack([x * r2 * r2, y * r2 * r2], axis=1),
          "p1": np.stack([2 * x * y, r2 + 2 * y * y], axis=1), "p2": np.stack([r2 + 2 * x * x, 2 * x * y], axis=1)}
    K2inv = np.linalg.inv(cam.K[:2, :2])
    dD |= {"cx": np.broadcast_to(K2inv[:, 0], (len(x), 2)), "cy": np.broadcast_to(K2inv[:, 1], (len(x), 2))}
    # J x' = -dD s, by J's inverse [[d, -b], [-b, a]] / det (a batched solve costs ten times more)
    out = {}
    for n, sig in sigmas.items():
        u, v = dD[n][:, 0], dD[n][:, 1]
        out[n] = np.stack([d * u - b * v, a * v - b * u], axis=1) * (-sig / det)[:, None]
    return out
