"""The one error type for bad user input (a malformed case file, an unknown engine, a NaN).

The CLI reports an `InputError` as one line naming what is wrong and what was expected, with
exit status 2 and no traceback.
"""


class InputError(ValueError):
    """Bad user input; the message names the file or option, the key and what was expected."""
