"""The names of a ``wandcal-capture/1`` folder's files and folders (docs/capture-format.md), in one place.

They live in ``drivers/`` because the lowest layer that opens a capture folder is here (the replay
driver reads ``rig.json``, ``sync.csv`` and ``frames/``); ``capture/`` and ``service/`` import them
from here. ``calib/`` reads no files, so its core is no home for file names.

    rig.json                the rig: cameras, wand, static object (capture/rig_file.py)
    wand.csv                the wand's blobs per frame and camera (the points level)
    static.csv              the static object's blobs per camera
    points.csv              labelled or unlabelled points (a capture without a wand)
    axis.csv                axis points that set the world frame
    floor.csv               points on the floor that set the world's vertical
    drop.csv                a dropped object's track that sets the world's vertical (gravity)
    blobs.csv               every blob of a live recording, before the wand filter
    take.csv                every blob of an ordinary take, unlabelled (wandcal watch)
    sync.csv                frame, trigger count and time, each camera's timestamp
    capture.json            the recording's log (rate, cameras' figures, messages)
    frames/<camera_id>/     the wand run's images (the image level)
    static/<camera_id>/     the static recording's images
    masks/<camera_id>.png   each camera's mask of always-bright regions
    background/<camera_id>/ an empty-volume recording
"""

RIG_FILE = "rig.json"
WAND_FILE = "wand.csv"
STATIC_FILE = "static.csv"
POINTS_FILE = "points.csv"
AXIS_FILE = "axis.csv"
FLOOR_FILE = "floor.csv"
DROP_FILE = "drop.csv"
BLOBS_FILE = "blobs.csv"
TAKE_FILE = "take.csv"
SYNC_FILE = "sync.csv"
LOG_FILE = "capture.json"
FRAMES_DIR = "frames"
STATIC_DIR = "static"
MASKS_DIR = "masks"
BACKGROUND_DIR = "background"
