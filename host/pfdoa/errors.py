"""Exceptions that the command line turns into one clear line and an exit code."""


class PfdoaError(Exception):
    """Base class for errors reported to the user without a traceback."""

    exit_code = 1


class ConfigError(PfdoaError):
    """A bad site/configuration file: `key` names what is wrong."""

    exit_code = 2

    def __init__(self, source: str, key: str, problem: str) -> None:
        self.source = source
        self.key = key
        self.problem = problem
        super().__init__(f"{source}: {key}: {problem}")


class InputError(PfdoaError):
    """A bad input file (trace, odometry, capture) or command-line value."""

    exit_code = 2


class OutputError(PfdoaError):
    """A requested output could not be opened, written or closed (a full disk, a closed
    pipe, no permission): exit status 1, after the run's counters (docs/security.md)."""

    exit_code = 1


class Interrupted(BaseException):
    """SIGINT or SIGTERM stopped a run (:mod:`pfdoa.signals`); what it finished is kept.
    The exit status is the shell's for that signal (128 + its number: 130, 143).

    Like KeyboardInterrupt it is not an Exception: a guard that keeps one bad input or
    one failed estimate from stopping the work (``except Exception``) must not keep the
    user's stop from stopping it either."""

    def __init__(self, signum: int, message: str) -> None:
        self.signum = signum
        self.exit_code = 128 + int(signum)
        super().__init__(message)
