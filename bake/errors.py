"""The bake's own error: a bake that cannot proceed for a reason the user can fix."""


class BakeError(RuntimeError):
    """A bake that cannot proceed for a reason the user can fix (message says how)."""
