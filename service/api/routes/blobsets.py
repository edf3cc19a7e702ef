"""Blob sets: frame sets streamed as centroids rather than images.

Commercial mocap cameras detect on board and send centroids, not images; a lab tool that has
them (or wandcal's own detector run elsewhere) posts them here, many sets a request. Nothing is
decoded, so a stream keeps up with a rig's rate where images cannot (docs/benchmarks.md, Load):
the sets land in the capture's wand.csv exactly as detected image frame sets would, and the
capture's guidance, jobs and coverage treat them alike.
"""

from __future__ import annotations

import numpy as np
from fastapi import APIRouter, HTTPException
from fastapi.concurrency import run_in_threadpool

from wandcal.service.api.deps import CaptureDep, State
from wandcal.service.schemas import MAX_BLOBS_PER_CAMERA, BlobSetsCreate, BlobSetsPublic, ErrorPublic
from wandcal.service.storage import DuplicateFrameSet

router = APIRouter(prefix="/captures", tags=["captures"])

# A blob centre lies on the image: pixel centres run from 0 to size - 1, and a centroid can sit
# up to half a pixel beyond the outermost ones.
EDGE_PX = 0.5


@router.post(
    "/{capture_id}/blobsets",
    status_code=201,
    response_model=BlobSetsPublic,
    responses={
        401: {"model": ErrorPublic, "description": "missing or wrong bearer token"},
        404: {"model": ErrorPublic, "description": "unknown capture"},
        409: {"model": ErrorPublic, "description": "a frame already received (nothing of the request is stored), "
                                                   "or the capture is not streamable"},
        413: {"model": ErrorPublic, "description": "request body over the upload limit"},
        422: {"model": ErrorPublic, "description": "a set names an unknown camera or a centre off its image"},
    },
    summary="Add frame sets as blob centroids (many per request); all are stored or none",
)
async def add_blobsets(body: BlobSetsCreate, capture: CaptureDep, state: State) -> BlobSetsPublic:
    """Cameras whose set holds exactly two blobs add both to the capture's wand observations."""
    rig = await run_in_threadpool(state.captures.rig, capture.id)
    cameras = {c.id: c for c in rig.cameras}
    seen: set[int] = set()
    sets = []
    for k, blob_set in enumerate(body.sets):
        where = f"sets[{k}] (frame {blob_set.frame})"
        if blob_set.frame in seen:
            raise HTTPException(422, f"{where}: frame {blob_set.frame} is given twice in this request")
        seen.add(blob_set.frame)
        blobs = {}
        for cam_id, centres in blob_set.blobs.items():
            camera = cameras.get(cam_id)
            if camera is None:
                raise HTTPException(422, f"{where}: {cam_id[:40]!r} is not a camera of this capture; "
                                         f"cameras: {', '.join(cameras)}")
            if len(centres) > MAX_BLOBS_PER_CAMERA:
                raise HTTPException(422, f"{where}: camera {cam_id} has {len(centres)} blobs, more than "
                                         f"{MAX_BLOBS_PER_CAMERA}; a flooded image holds no wand")
            uv = np.array(centres, dtype=float).reshape(-1, 2)
            off = (uv < -EDGE_PX).any(1) | (uv[:, 0] > camera.width - 1 + EDGE_PX) | (uv[:, 1] > camera.height - 1 + EDGE_PX)
            if off.any():
                u, v = uv[np.flatnonzero(off)[0]]
                raise HTTPException(422, f"{where}: camera {cam_id}'s blob ({u:g}, {v:g}) lies off its "
                                         f"{camera.width} x {camera.height} image; send raw pixel centres, "
                                         "origin at the top-left pixel's centre")
            blobs[cam_id] = uv
        sets.append((blob_set.frame, blob_set.trigger_count, blobs))
    try:
        row = await run_in_threadpool(state.captures.append_framesets, capture.id, sets)
    except DuplicateFrameSet as exc:
        raise HTTPException(409, f"{exc}; nothing of this request was stored") from None
    wand_rows = sum(2 for _, _, blobs in sets for uv in blobs.values() if len(uv) == 2)
    return BlobSetsPublic(capture_id=capture.id, stored=len(sets), wand_rows=wand_rows, framesets=row.framesets)
