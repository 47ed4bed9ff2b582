"""Root of hlr-lab's one exception tree.

It lives in the lowest layer because ``drivers`` may import nothing of the project, yet its
device errors must belong to the same tree as the application's input errors
(``HlrLabError`` → device errors | input errors). The application re-exports it from
:mod:`hlr_lab.errors`.
"""


class HlrLabError(Exception):
    """Any failure hlr-lab reports to its user: the message says what is wrong and what to do."""
