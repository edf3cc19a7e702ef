"""Advice on the sets a capture's cameras missed: a camera that missed many more than the others points at
its trigger input or link; every camera missing many, at the machine falling behind the rate. Told as the
capture ends (``wandcal capture``'s stderr, the service's live status) and kept in ``capture.json``'s messages."""

from __future__ import annotations

MISSED_SHARE = 0.1  # a camera that missed more of the sets than this gets a word of advice


def missed_advice(per_camera: dict[str, dict], sets: int) -> list[str]:
    """What to do when cameras missed many of the ``sets``: a camera that missed more than
    :data:`MISSED_SHARE` of them beyond the camera that missed fewest, its trigger input or link; every camera
    past :data:`MISSED_SHARE`, the machine falling behind the rate. No line when neither."""
    if not sets or not per_camera:
        return []
    share = {cid: s["missed"] / sets for cid, s in per_camera.items()}
    best = min(share, key=share.__getitem__)
    floor = share[best] if len(share) > 1 else 0.0
    lines = []
    apart = [cid for cid, v in share.items() if v - floor > MISSED_SHARE]
    if apart:
        lo, hi = min(share[c] for c in apart), max(share[c] for c in apart)
        span = f"{hi:.0%}" if round(100 * lo) == round(100 * hi) else f"{100 * lo:.0f}-{hi:.0%}"
        where = f" where {best} missed {floor:.0%}" if len(share) > 1 else ""
        lines.append(f"{', '.join(apart)} missed {span} of the {sets} sets{where}: "
                     + ("lower --rate, or " if len(share) == 1 else "")
                     + f"check {'its' if len(apart) == 1 else 'their'} trigger input, cable and link (bandwidth)")
    if floor > MISSED_SHARE:
        lines.append(f"every camera missed {floor:.0%} of the {sets} sets or more: this machine did not keep up with "
                     "the rate; lower --rate, record fewer cameras at once, or free the CPU (the recording is kept as it is)")
    return lines
