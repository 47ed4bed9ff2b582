"""Root of hlr-lab's one exception tree, and the device errors.

It lives in the lowest layer because ``drivers`` may import nothing of the project, yet its device
errors must belong to the same tree as the application's input errors
(``HlrLabError`` → device errors | input errors). The application re-exports it from
:mod:`hlr_lab.errors`. SDK result codes never leave ``drivers``: they become these exceptions.
"""

# ``extra`` of the log record of every retried device exchange: the acquisition journals and counts them
RETRY = {"retry": True}


class HlrLabError(Exception):
    """Any failure hlr-lab reports to its user: the message says what is wrong and what to do."""


class DeviceError(HlrLabError):
    """A device misbehaved; ``device`` names it (e.g. "gantry servo 2 on /dev/ttyUSB0")."""

    def __init__(self, message: str, *, device: str):
        self.device, self.reason = device, message  # the message without the device's name
        super().__init__(f"{device}: {message}")


class DeviceTimeout(DeviceError):
    """The device did not answer in time."""


class ChecksumError(DeviceError):
    """A reply arrived corrupted (bad CRC or framing)."""


class DeviceFault(DeviceError):
    """The device answered with an error code (``code``), e.g. a data-limit or access error."""

    def __init__(self, message: str, *, device: str, code: int):
        self.code = code
        super().__init__(message, device=device)


class HardwareAlarm(DeviceError):
    """The device reports a hardware error (overload, overheating…); ``status`` holds its bits."""

    def __init__(self, message: str, *, device: str, status: int):
        self.status = status
        super().__init__(message, device=device)


class LimitError(DeviceError):
    """A commanded position lies outside the configured limits; nothing was sent."""


class SettleTimeout(DeviceError):
    """An axis did not reach its goal within the time allowed (stuck, or too slow)."""
