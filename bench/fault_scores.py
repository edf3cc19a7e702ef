"""How bench/real_faults.py's outcomes are counted and shown: a target camera's displacement
covered by its honest sigma, the confusion table by fault family, one line a case, and the honest
sigma's coverage on the focal cases. Its names are importable from bench/real_faults.py too.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from bench.real_faults import Outcome

ABSORBED_SIGMAS = 3.0  # a principal point the rotation absorbs moves the camera within this many sigma
OUTCOMES = ("right", "absorbed", "limited", "at the limit", "missed", "wrong kind", "wrong camera", "called poor", "refused")



def at_limit_lines(verdict: dict) -> list[str]:
    """The verdict's criteria at the limit of poor, each as the CLI summary says it ("cam1 own
    noise against the other cameras' at the limit of poor (1.32 +- 0.11 x against 1.5 x)")."""
    from wandcal.calib.judge.verdict import at_limit_text

    return [f"{e['camera'] + ' ' if e.get('camera') else ''}{e['criterion']} {at_limit_text(e)}"
            for e in verdict.get("at_limit") or [] if isinstance(e, dict) and e.get("levels", [None, None])[1] == "poor"]


def noise_at_limit_named(o: Outcome, camera: str | None) -> bool:
    """A noise case is *at the limit* (right) when the verdict says the target camera's noise is at
    the limit of poor: a line of :func:`at_limit_lines` that names the camera and the noise."""
    return camera is not None and any(line.startswith(camera + " ") and "noise" in line for line in o.at_limit)


def covered(o: Outcome, sigmas: float = ABSORBED_SIGMAS) -> bool:
    """The target camera's displacement is within ``sigmas`` of its honest sigma (the geometry
    sigma with its focal length's, wandcal.calib.judge.intrinsic_limits)."""
    return o.displacement_mm is not None and o.honest_sigma_mm is not None and o.displacement_mm <= sigmas * o.honest_sigma_mm

def confusion_table(outcomes: list[Outcome], families: tuple[str, ...], notes: dict[str, str] | None = None) -> str:
    """The confusion table by fault family (markdown), rows in the order of ``families``: runs,
    right, and what the wrong ones were; the target camera's median displacement over its reported
    sigma. notes: family -> why it cannot be determined (a note in its row; left out of the
    *all determinable* line)."""
    notes = notes or {}
    lines = ["| fault | runs | right | " + " | ".join(OUTCOMES[1:]) + " | displacement / sigma (median) | note |",
             "|---|---|---|" + "---|" * (len(OUTCOMES) - 1) + "---|---|"]
    total = right = 0
    scored_total = scored_right = 0
    for family in families:
        rows = [o for o in outcomes if o.case.family == family]
        if not rows:
            continue
        counts = {k: sum(o.outcome == k for o in rows) for k in OUTCOMES}
        ok = sum(o.right for o in rows)
        ratio = [o.displacement_mm / o.sigma_mm for o in rows if o.displacement_mm is not None and o.sigma_mm]
        median = f"{np.median(ratio):.1f}" if ratio else "-"
        lines.append(f"| {family} | {len(rows)} | {ok} ({100 * ok / len(rows):.0f}%) | "
                     + " | ".join(str(counts[k]) for k in OUTCOMES[1:]) + f" | {median} | {notes.get(family, '')} |")
        total += len(rows)
        right += ok
        if family not in notes:
            scored_total += len(rows)
            scored_right += ok
    lines.append(f"| **all** | {total} | {right} ({100 * right / max(total, 1):.0f}%) |" + " |" * (len(OUTCOMES) + 1))
    lines.append(f"| **all determinable** | {scored_total} | {scored_right} ({100 * scored_right / max(scored_total, 1):.0f}%)"
                 " | " + " |" * (len(OUTCOMES)))
    return "\n".join(lines)


def case_line(o: Outcome) -> str:
    """One case as a line of text: session, label, outcome, verdict, faults, displacement and sigma."""
    honest = f", honest {o.honest_sigma_mm:.2f}" if o.honest_sigma_mm is not None else ""
    limited = f" limits: {', '.join(o.limited_by)}" if o.limited_by else ""
    disp = f" moved {o.displacement_mm:.1f} mm (sigma {o.sigma_mm:.2f}{honest}){limited}" if o.displacement_mm is not None and o.sigma_mm else ""
    off = f" offset {o.offset_frames:+.2f}" if o.offset_frames is not None else ""
    return f"{o.case.session:20s} {o.case.label:32s} {o.outcome:12s} {o.level:9s} {o.named}{disp}{off}"


def sigma_coverage(outcomes: list[Outcome], max_error: float = 0.03, families: tuple[str, ...] = ("focal",)) -> str:
    """The honest sigma's coverage on the cases of ``families`` (the focal ones at most ``max_error``
    off): the share of target cameras whose displacement is within 1, 2 and 3 of their honest sigma
    (and of their geometry sigma alone), and the share covered within 3 sigma or with the fault's
    intrinsic named as its limit."""
    rows = [o for o in outcomes if o.case.family in families
            and (o.case.family != "focal" or abs(o.case.size - 1) <= max_error + 1e-9)
            and o.displacement_mm is not None and o.honest_sigma_mm is not None]
    what = (f"Focal length within {100 * max_error:.0f}%" if families == ("focal",) else ", ".join(families))
    if not rows:
        return f"{what}: no cases with an honest sigma"

    def share(test) -> str:
        n = sum(bool(test(o)) for o in rows)
        return f"{n}/{len(rows)} ({100 * n / len(rows):.0f}%)"

    parts = [f"within {k} sigma: honest {share(lambda o, k=k: covered(o, k))}, geometry alone "
             f"{share(lambda o, k=k: o.sigma_mm and o.displacement_mm <= k * o.sigma_mm)}" for k in (1, 2, 3)]
    return (f"{what}, {len(rows)} target cameras: " + "; ".join(parts)
            + f"; within 3 honest sigma or the fault's intrinsic named as its limit: {share(lambda o: covered(o) or o.limited)}"
            + f"; within 3 honest sigma and named (limited): {share(lambda o: covered(o) and o.limited)}")


def before_line(outcomes: list[Outcome], families: tuple[str, ...]) -> str:
    """The families' right counts as session 15 scored them (``right_before``: limited only for the
    focal families, with the camera named in any limit), beside today's."""
    parts = []
    for family in families:
        rows = [o for o in outcomes if o.case.family == family]
        if rows:
            parts.append(f"{family} {sum(o.right_before for o in rows)}/{len(rows)} (now {sum(o.right for o in rows)})")
    return "Scored as in session 15, from the same runs: " + ", ".join(parts)
