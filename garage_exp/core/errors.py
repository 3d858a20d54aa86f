"""User-facing errors: one line that names the file and the place."""


class GarageError(Exception):
    """Bad input or an unusable environment; the CLI prints the message alone and exits 2."""

    def __init__(self, message: str, where: str | None = None):
        self.where = where
        super().__init__(f"{where}: {message}" if where else message)

    def again(self, message: str, where: str | None) -> "GarageError":
        """The same kind of refusal said at another place (a scenario's file, a search's override)."""
        return type(self)(message, where)


class JobFault(RuntimeError):
    """An expected fault of the world a job depends on, met mid-job (a model server that died): the job's run ends
    FAILED with it and keeps the frames scored before it; the command says it in one line, without a traceback,
    and exits 1 (docs/reliability.md). Unlike a GarageError nothing was wrong with the input."""


class Screened(Exception):
    """A draw that its caller's screen turned down once the case's actors were placed, before the garage around
    them was built (a search's requirements, search/require.py `first_look`): not an error, a verdict, which it
    carries for the caller that set the screen."""

    def __init__(self, verdict):
        super().__init__(getattr(verdict, "why", ""))
        self.verdict = verdict


def check_range(value, lo: float, hi: float, where: str, what: str = "") -> None:
    """GarageError naming `where` unless lo <= value <= hi (a non-number is out of range too)."""
    try:
        ok = lo <= float(value) <= hi
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise GarageError(f"{what or value} is outside {lo:g}-{hi:g}", where)


def did_you_mean(word: str, options) -> str:
    """' (did you mean ...?)' with the option nearest to `word` (difflib), else ' (have: a, b, ...)'."""
    import difflib

    options = [str(o) for o in options]
    close = difflib.get_close_matches(str(word), options, n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else f" (have: {', '.join(options)})"


class Infeasible(GarageError):
    """Values each fine on their own that together put two actors in one another (scenario/place.py `clash`):
    a job refuses it as bad input; a search prunes the trial as infeasible and goes on (Scenic rejects such
    samples too). `actors`: the two actors."""

    def __init__(self, message: str, where: str | None = None, actors: tuple[str, ...] = ()):
        super().__init__(message, where)
        self.actors = tuple(actors)

    def again(self, message: str, where: str | None) -> "Infeasible":
        return Infeasible(message, where, self.actors)
