"""The commands used at the rig while recording: ``capture`` (cameras and the trigger into a capture
folder), ``detect`` (blobs from a folder's images), ``trigger-emulator`` (a strobe trigger on a
pseudo-terminal, for trying the capture without a board) and ``guidance`` (where to wave next).

| module | command |
|---|---|
| :mod:`~wandcal.service.cli.recording.capture` | ``wandcal capture`` |
| :mod:`~wandcal.service.cli.recording.detect` | ``wandcal detect`` |
| :mod:`~wandcal.service.cli.recording.trigger` | ``wandcal trigger-emulator`` |
| :mod:`~wandcal.service.cli.recording.guidance` | ``wandcal guidance`` |
"""
