"""User-facing errors.

Public: ``WarpbwError``.

Anything the user can cause (a bad file, a bad key in a scene, a bad CLI value) is raised as
``WarpbwError`` with a one-line message that names the file or key and says what was expected.
The CLIs print it as ``warpbw: error: <message>`` and exit with status 2, never a traceback.
"""


class WarpbwError(Exception):
    """A problem with the user's input, reported in one line without a traceback."""
