"""The command line's exit codes, one table for every command (README "Exit codes", each command's
``--help``), and :class:`InputError`, the error a command raises for input it refuses."""

from __future__ import annotations

OK = 0
FAULT = 1  # a judged fault: check saw a camera move, calibrate --require found the verdict below it
BAD_INPUT = 2  # the message names the file, option, camera or frame and says what to fix
NO_ANSWER = 3  # a device or port stopped answering mid-way, or check could not judge
INTERRUPTED = 130  # Ctrl-C, end of input or a closed terminal (128 + SIGINT, as shells report it)

TABLE = (
    "exit status: 0 done; 1 a judged fault (check: a camera moved; calibrate --require: the verdict is below it); "
    "2 bad input (the message says what to fix); 3 no answer (a camera or the trigger stopped mid-way, or check "
    "could not judge); 130 interrupted (Ctrl-C, end of input, closed terminal: what was done is kept and named; "
    "serve stops on Ctrl-C or SIGTERM as its normal end, with 0)"
)


# a path the user named that is not there, or is of the wrong kind: bad input, not a device's silence
PATH_ERRORS = (FileNotFoundError, FileExistsError, NotADirectoryError, IsADirectoryError)


class InputError(ValueError):
    """Input a command refuses before it starts (a folder that holds a capture, a trigger port
    that is not there, a taken port): exit :data:`BAD_INPUT` with the message."""
