"""User-facing errors: one line that names the file and the place."""


class GarageError(Exception):
    """Bad input or an unusable environment; the CLI prints the message alone and exits 2."""

    def __init__(self, message: str, where: str | None = None):
        self.where = where
        super().__init__(f"{where}: {message}" if where else message)
