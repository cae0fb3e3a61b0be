"""Errors a user can cause. The CLI prints them as one line and exits with code 2."""


class UserError(Exception):
    """A bad input (file, value, option) — reported as one clear line naming the value, exit 2."""
