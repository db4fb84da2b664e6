"""The pytest plugin's port for the run: which one (``--lm629-port``, ``--lm629-profile``),
whether it is simulated, and a real one's transport opened once and kept for the run, with
the stop signals guarded (see :mod:`lm629_host.integrations.pytest_plugin` for why)."""

from __future__ import annotations

import signal
from pathlib import Path
from typing import Any

import pytest

from lm629_host.chip.safety import StopSignals
from lm629_host.errors import LM629Error
from lm629_host.transports import DEFAULT_URL, transport_class
from lm629_host.transports.base import Transport
from lm629_host.transports.ports import profile_port, resolve_port, twin_port
from lm629_host.urls import PortURL, query_params, with_query


class PortError(Exception):
    """The chosen port cannot be opened: one message for the whole run."""


class PortSession:
    """The run's port: what it is, whether it is simulated, and the open transport of a real
    one (kept for the run)."""

    def __init__(self, config: pytest.Config) -> None:
        self.profile: Path | None = None
        self.profile_data: Any = None  #: the loaded lm629_host.config.profile.Profile
        profile = config.getoption("lm629_profile", None)
        port = config.getoption("lm629_port", None)
        if profile is not None:
            self.profile = Path(profile)
            self.profile_data = load_profile(self.profile)
            if port is None:
                try:
                    port = profile_port(self.profile_data)
                except ValueError as exc:
                    raise pytest.UsageError(f"--lm629-profile {profile}: {exc}") from None
        self.url: str | PortURL = port or DEFAULT_URL
        self.allow_motion: bool = bool(config.getoption("lm629_allow_motion", False))
        self._transport: Transport | None = None
        self._signals = StopSignals(interrupted)
        self._checked = False
        try:
            self.simulated = transport_class(self.url).simulated
        except LM629Error as exc:
            raise pytest.UsageError(f"--lm629-port {self.url}: {exc}") from None
        if self.simulated and self.profile_data is not None:
            # a simulated port with a profile: the twin of its bench, built from the plants
            self.url = twin_port(self.profile_data, self.url)

    def check(self) -> None:
        """Open the port once (a simulator: build one chip and drop it), or PortError."""
        if self._checked:
            return
        if self.simulated:
            try:
                resolve_port(sim_url(self.url, {})).open_transport().close()
            except (LM629Error, ValueError) as exc:
                raise PortError(f"--lm629-port {self.url}: {exc}") from None
        else:
            self.transport()
        self._checked = True

    def transport(self) -> Transport:
        """The real port's transport, opened at the first call."""
        if self._transport is None:
            try:
                self._transport = resolve_port(self.url).open_transport()
            except (LM629Error, ValueError, OSError) as exc:
                raise PortError(f"--lm629-port {self.url} cannot be opened: {exc}") from None
            self._install_signals(self._transport)
        return self._transport

    def _install_signals(self, transport: Transport) -> None:
        """Ctrl-C, SIGTERM and SIGHUP (a CI job's timeout, a closed terminal) end the run as
        an interrupted one, so that the fixtures' teardown stops a moving motor (without this
        SIGTERM and SIGHUP would kill pytest where it stands).  A signal that arrives during a
        bus program is held until the program has ended, as the CLI does
        (:class:`~lm629_host.chip.safety.StopSignals`), so that the stop starts on a clean bus."""
        self._signals.guard(transport)
        self._signals.install()

    def close(self) -> None:
        self._signals.restore()
        if self._transport is not None:
            self._transport.close()
            self._transport = None


def interrupted(signum: int) -> KeyboardInterrupt:
    """A stop signal as pytest's interrupted run, naming the signal."""
    return KeyboardInterrupt(f"{signal.Signals(signum).name}: the lm629 fixtures stop the motor")


def load_profile(path: Path) -> Any:
    """The board profile at ``path`` (:mod:`lm629_host.config.profile`), or one usage error naming
    the file, the line and the key."""
    from lm629_host.config import profile as profiles
    try:
        return profiles.load_profile(path)
    except ValueError as exc:  # ProfileError: file, line and key in one line
        raise pytest.UsageError(f"--lm629-profile {path}: {exc}") from None


def sim_url(base: str | PortURL, params: dict[str, str]) -> str | PortURL:
    """The simulator URL of a test: the port's own parameters, the marker's over them, and
    ``strict=1`` unless one of them says otherwise."""
    values = dict(params)
    if "strict" not in query_params(base) and "strict" not in values:
        values["strict"] = "1"
    return with_query(base, values)
