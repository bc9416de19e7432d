"""File formats fitlab reads and writes. Every reader validates its input and raises
:class:`fitlab.errors.InputFileError` naming the file, line and column; every writer writes
atomically (temporary file, then rename)."""
