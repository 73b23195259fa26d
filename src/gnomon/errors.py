"""The one error type for bad input, so the command line can print it as one line.

``InputError`` is a ``ValueError`` that carries where the problem is: the file,
the field (or scenario key / command-line option) and the first bad row. Library
code raises it; ``gnomon.cli`` prints ``str(err)`` and exits with status 2.
"""

from __future__ import annotations


class InputError(ValueError):
    """Bad input data: names the file (when known), the field and the first bad row."""

    def __init__(self, message: str, *, file: str | None = None, field: str | None = None,
                 row: int | None = None):
        self.message = " ".join(str(message).split())  # always one line
        self.file = file
        self.field = field
        self.row = row
        super().__init__(self._format())

    def _format(self) -> str:
        where = []
        if self.file is not None:
            where.append(f"{self.file}")
        if self.field is not None:
            where.append(f"field '{self.field}'")
        if self.row is not None:
            where.append(f"row {self.row}")
        return (": ".join([", ".join(where), self.message]) if where else self.message)

    def with_file(self, file: str) -> InputError:
        """The same error, naming ``file`` (readers add it to errors from ``Recording``)."""
        return InputError(self.message, file=str(file), field=self.field, row=self.row)
