"""The outward face of wandcal: the command line, and the HTTP service with its job queue."""
