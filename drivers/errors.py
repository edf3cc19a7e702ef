"""The root error of the drivers package.

A driver raises :class:`DriverError` (an ``OSError``) for a hardware or file fault; the message
names the device (URL, camera id, frame file or port) and says what to do next.
"""

from __future__ import annotations


class DriverError(OSError):
    """A camera, trigger or file source failed. The message names the device and the next step."""


class FrameTimeout(DriverError):
    """No frame arrived within the read timeout (a triggered camera waits for its next pulse)."""


class FrameError(DriverError):
    """One frame could not be read (a corrupt file, a short transfer); the stream goes on.

    Attributes:
        sequence: the sequence number of the lost frame, so the layer above can leave its slot empty.
    """

    def __init__(self, message: str, sequence: int):
        super().__init__(message)
        self.sequence = sequence


class CameraUrlError(DriverError):
    """A camera URL that names no device or asks for what a driver cannot do (bad input, not a
    device fault: the command line exits 2 on it)."""
