"""The service's data folder: one owner at a time, what a start recovers after a crash, and what
old captures and results are removed (only as the settings allow).

| module | holds |
|---|---|
| :mod:`~wandcal.service.datafolder.lock` | the owner's lock on the folder (a crash releases it) |
| :mod:`~wandcal.service.datafolder.recovery` | what a start does after a crash so that nothing recorded is lost |
| :mod:`~wandcal.service.datafolder.retention` | the retention policy for old captures and results |
"""
