"""Turns driver output into synchronised frame sets and capture folders (``wandcal-capture/1``)."""
