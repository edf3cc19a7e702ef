"""The verdict's ``limits`` in words a lab user can act on: which given intrinsic limits where the
cameras stand, by how much, and what to do; the CLI summary and the report's page print the same lines.

Which intrinsics are named is :mod:`wandcal.calib.judge.intrinsic_limits`' rule (decision 0086:
a part of the honest sigma over ``LIMIT_RATIO`` times the geometry sigma). This is presentation:
each camera's named intrinsics are ranked by their part and the **dominant** ones said plainly,
those whose part is at least ``LIMIT_RATIO`` times the camera's largest. The argument is 0086's,
applied to the largest part instead of the geometry sigma: a part under it, added in quadrature to
the largest, raises it by less than a sigma's own standard error (11%), so giving that intrinsic
exactly would not change what the result can say while the largest stays. The rest are one short
clause ("matter less"), their figures in the result's ``verdict.limits`` (and each camera's
``focal_limit`` / ``lens_limits``).

Cameras with the same dominant intrinsics (and the same advice) share a line pair, the pair of the
largest part first::

    limit (cam1, cam2 and cam3): their positions hinge on the focal length, +-55-61 mm (27-30 mm along
      the axis for each 1%; rig.json gives no focal_std_px: 2% assumed), against +-0.34-0.47 mm from
      the geometry alone
      to do: refine it (--refine-intrinsics focal: this capture determines it) or give it from a lens
      calibration, with its focal_std_px; k1, cx and k2 matter less (up to 6.4 mm: verdict.limits)
"""

from __future__ import annotations

from wandcal.calib.judge.intrinsic_limits import LIMIT_RATIO
from wandcal.calib.rig import camera_list

FOCAL = "focal length"
ORDER = (FOCAL, "cx", "cy", "k1", "k2", "p1", "p2")
FLAGS = {FOCAL: "focal", "cx": "principal", "cy": "principal", "k1": "k1"}  # --refine-intrinsics' names
MAX_GROUPS = 3  # line pairs at most; cameras of further groups are named on one line, their figures in the result
ASSUMED = "assumed, rig.json giving no focal_std_px"  # intrinsic_limits.limited_cameras' words on an assumed sigma


def parameter(limit: dict) -> str:
    """The limit's intrinsic: "focal length" (results before lens limits have no ``parameter``), cx, ..., p2."""
    return str(limit.get("parameter", FOCAL))


def figure(limit: dict, name: str) -> tuple[float | None, str]:
    """The limit's evidence ``name`` (``focal_sigma``, ``parameter_sigma``, ``geometry_sigma``): the
    ``_mm`` form of a scaled result, else the rig's units; and its unit ("mm" or "units")."""
    evidence = limit.get("evidence") or {}
    if evidence.get(f"{name}_mm") is not None:
        return float(evidence[f"{name}_mm"]), "mm"
    value = evidence.get(name)
    return (None if value is None else float(value)), "units"


def part(limit: dict) -> float | None:
    """What the limit's intrinsic, off by its sigma, moves the camera (mm, or the rig's units)."""
    return figure(limit, "focal_sigma" if parameter(limit) == FOCAL else "parameter_sigma")[0]


def determined(limit: dict) -> bool:
    """This capture determines the limit's intrinsic (its message says to refine it)."""
    return "--refine-intrinsics" in str(limit.get("message", ""))


def ranked(limits: list[dict]) -> tuple[list[dict], list[dict]]:
    """One camera's limits, largest part first, split into the dominant ones (part at least
    ``LIMIT_RATIO`` times the largest) and the rest."""
    order = sorted(limits, key=lambda lim: -(part(lim) or 0.0))
    top = part(order[0]) or 0.0
    dominant = [lim for lim in order if (part(lim) or 0.0) >= LIMIT_RATIO * top]
    return dominant, order[len(dominant):]


def limit_lines(limits: list[dict], n_cameras: int) -> list[str]:
    """The summary's lines for the verdict's ``limits`` (see the module's docstring): for each group
    of cameras with the same dominant intrinsics, what their positions hinge on and what to do;
    each limit's own message where a result's figures are absent (an older result)."""
    limits = [lim for lim in limits if isinstance(lim, dict) and lim.get("camera")]
    if not limits:
        return []
    if any(part(lim) is None or figure(lim, "geometry_sigma")[0] is None for lim in limits):
        return [f"  limit ({lim['camera']}): {lim.get('message', '')}" for lim in limits]
    cams = list(dict.fromkeys(lim["camera"] for lim in limits))
    groups: dict[tuple, list[tuple[str, list[dict], list[dict]]]] = {}
    for cam in cams:
        dominant, rest = ranked([lim for lim in limits if lim["camera"] == cam])
        key = tuple(sorted(((parameter(lim), determined(lim)) for lim in dominant), key=lambda k: _rank(k[0])))
        groups.setdefault(key, []).append((cam, dominant, rest))
    # the group of the largest part first: a big rig's lines past MAX_GROUPS are its smallest limits
    order = sorted(groups.values(), key=lambda members: -max(part(lim) or 0.0 for _, d, _ in members for lim in d))
    out: list[str] = []
    for members in order[:MAX_GROUPS]:
        out += _group_lines(members, n_cameras)
    left = [cam for members in order[MAX_GROUPS:] for cam, _, _ in members]
    if left:
        out.append(f"  limit ({camera_list(left, n_cameras)}): given intrinsics limit these cameras' positions too "
                   "(the result's verdict.limits has each camera's figures and what to do)")
    return out


def _rank(name: str) -> int:
    return ORDER.index(name) if name in ORDER else len(ORDER)


def _span(values: list[float], fmt: str = ".2g") -> str:
    """A range of figures, "0.68-1.7", or one figure where they print alike."""
    low, high = format(min(values), fmt), format(max(values), fmt)
    return low if low == high else f"{low}-{high}"


def _listed(names: list[str]) -> str:
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]


def _nouns(names: list[str]) -> str:
    """Intrinsics named as things to refine or give: "the focal length and k1"."""
    return _listed([f"the {n}" if n == FOCAL else n for n in names])


def _group_lines(members: list[tuple[str, list[dict], list[dict]]], n_cameras: int) -> list[str]:
    """The line pair of cameras sharing their dominant intrinsics: members (camera, its dominant
    limits, the rest)."""
    cams = [cam for cam, _, _ in members]
    several = len(cams) > 1
    unit = figure(members[0][1][0], "geometry_sigma")[1]
    names = sorted({parameter(lim) for _, dominant, _ in members for lim in dominant}, key=_rank)
    clauses = [_clause(name, [lim for _, dominant, _ in members for lim in dominant if parameter(lim) == name], unit)
               for name in names]
    geo = [figure(dominant[0], "geometry_sigma")[0] or 0.0 for _, dominant, _ in members]
    head = (f"  limit ({camera_list(cams, n_cameras)}): {'their positions hinge' if several else 'its position hinges'} "
            f"on {_listed(clauses)}, against +-{_span(geo)} {unit} from the geometry alone")
    return [head, "    to do: " + _todo(members, names, unit)]


def _evidence(limits: list[dict], *names: str) -> list[float] | None:
    """Each limit's first evidence figure of ``names`` present, or None where one has none."""
    out = []
    for lim in limits:
        evidence = lim.get("evidence") or {}
        value = next((evidence[n] for n in names if evidence.get(n) is not None), None)
        if value is None:
            return None
        out.append(float(value))
    return out


def _clause(name: str, limits: list[dict], unit: str) -> str:
    """One dominant intrinsic with its part over the group's cameras and what its sigma is:
    "the focal length, +-55-61 mm (27-30 mm along the axis for each 1%; rig.json gives no
    focal_std_px: 2% assumed)"."""
    parts = _span([part(lim) or 0.0 for lim in limits])
    if name == FOCAL:
        per = _evidence(limits, "along_axis_mm_per_percent", "along_axis_per_percent")
        known = _evidence(limits, "focal_std_percent")
        assumed = sum(ASSUMED in str(lim.get("message", "")) for lim in limits)
        along = f"{_span([abs(p) for p in per])} {unit} along the axis for each 1%; " if per is not None else ""
        if known is None:
            sigma = "off by its assumed uncertainty"
        elif assumed == len(limits):
            sigma = f"rig.json gives no focal_std_px: {_span(known, 'g')}% assumed"
        else:
            sigma = f"known to {_span(known, 'g')}%, rig.json's focal_std_px{' or assumed' if assumed else ''}"
        return f"the focal length, +-{parts} {unit} ({along}{sigma})"
    sigmas = _evidence(limits, "sigma")
    px = " px" if (limits[0].get("evidence") or {}).get("unit") == "px" else ""
    of = f" (for {_span(sigmas, '.2g')}{px}, its assumed uncertainty)" if sigmas is not None else ""
    return f"{name}, +-{parts} {unit}{of}"


def _todo(members: list[tuple[str, list[dict], list[dict]]], names: list[str], unit: str) -> str:
    """What to do about the group's dominant intrinsics (refine those this capture determines, or
    give them from a lens calibration), then the rest in one clause."""
    dominant = [lim for _, d, _ in members for lim in d]
    known = [n for n in names if all(determined(lim) for lim in dominant if parameter(lim) == n)]
    unknown = [n for n in names if n not in known]
    said = []
    if known:
        it = "it" if len(known) == 1 else "them"
        flags = ",".join(dict.fromkeys(FLAGS[n] for n in known if n in FLAGS))
        std = (", with its focal_std_px" if len(known) == 1 else ", with the focal length's focal_std_px") if FOCAL in known else ""
        said.append(f"refine {_nouns(known) if len(known) > 1 or unknown else it} (--refine-intrinsics {flags}: this "
                    f"capture determines {it}) or give {it} from a lens calibration{std}")
    if unknown:
        it = "it" if len(unknown) == 1 else "them"
        std = (", with its focal_std_px" if len(unknown) == 1 else ", with the focal length's focal_std_px") \
            if FOCAL in unknown else ""
        said.append(f"give {_nouns(unknown) if known or len(unknown) > 1 else it} from a lens "
                    f"calibration{std} (this capture does not determine {it})")
    rest = [lim for _, _, r in members for lim in r]
    if rest:
        less = sorted({parameter(lim) for lim in rest}, key=_rank)
        said.append(f"{_listed(less)} matter{'s' if len(less) == 1 else ''} less (up to "
                    f"{max(part(lim) or 0.0 for lim in rest):.2g} {unit}: the result's verdict.limits)")
    return "; ".join(said)
