"""Errors that wavlight reports to users as one line (the CLI exits with code 2)."""


class WavlightError(Exception):
    """Bad input or an unusable system: the message is meant for the user as is."""


class SceneError(WavlightError):
    """A problem in a scene file, naming the file and the key."""

    def __init__(self, path, key: str, message: str):
        self.path, self.key = str(path), key
        super().__init__(f"{path}: {key}: {message}" if key else f"{path}: {message}")
