"""A labgrid driver: an LM629 (or a Board of them) on a labgrid serial port.

    pip install 'lm629-host[labgrid]'

In a labgrid environment YAML (docs/testing.md, examples/labgrid/)::

    targets:
      main:
        resources:
          RawSerialPort: {port: /dev/ttyACM0}       # or NetworkSerialPort (an exporter's bench)
        drivers:
          LM629Driver: {}
    imports:
      - lm629_host.integrations.labgrid_driver

and in a test run by labgrid's pytest plugin (``pytest --lg-env env.yaml``)::

    def test_axis(target):
        drv = target.get_driver("LM629Driver")
        chip = drv.chip()            # an LM629, reset
        board = drv.get_board()      # the Board: every chip select of the bridge, reset

The driver opens the bridge through lm629-host's own serial transport (the bridge protocol,
its handshake and its faster rate), so it binds the port resource, not labgrid's
``SerialDriver`` (two drivers cannot own one port).  A ``NetworkSerialPort`` is reached as
``rfc2217://HOST:PORT`` (an exporter's ser2net) or, with ``protocol: raw``,
``socket://HOST:PORT`` (ser2net raw, or ``lm629 sim serve --tcp``)
(:func:`lm629_host.integrations.labgrid_place.network_port_url`).  ``options:`` are the port
URL's options (``{fast_baud: 115200, failsafe: 0.5}``), passed through.  Deactivating the
driver stops every axis that still moves (abrupt stop, then motor off) and closes the port.

labgrid installs its own fork of pyserial (pyserial-labgrid): keep this extra in a virtual
environment of its own (docs/testing.md).
"""

from __future__ import annotations

from collections.abc import Mapping

import attr
from labgrid.driver.common import Driver
from labgrid.factory import target_factory
from labgrid.resource.common import Resource
from labgrid.util.proxy import proxymanager

import lm629_host
from lm629_host.errors import LM629Error
from lm629_host.integrations.labgrid_place import network_port_url
from lm629_host.urls import PortURL
from lm629_host.chip.safety import emergency_stop


def port_url(port: Resource, options: Mapping[str, object] | None = None) -> str:
    """The lm629-host URL of a labgrid ``SerialPort`` / ``RawSerialPort`` / ``USBSerialPort``
    or ``NetworkSerialPort`` (through labgrid's proxy manager, so ``LG_PROXY`` works), with
    ``options``: any option a port URL takes, passed through as they are."""
    if type(port).__name__ == "NetworkSerialPort" or hasattr(port, "protocol"):
        host, number = proxymanager.get_host_and_port(port)
        return network_port_url(host, number, port.speed, getattr(port, "protocol", "rfc2217"),
                                options).text
    return PortURL.parse(f"serial://{port.port}").with_options(
        {"baud": str(port.speed), **{k: _text(v) for k, v in (options or {}).items()}}).text


def _text(value: object) -> str:
    return ("1" if value else "0") if isinstance(value, bool) else str(value)


@target_factory.reg_driver
@attr.s(eq=False)
class LM629Driver(Driver):
    """An LM628/LM629 board behind a bridge on a labgrid serial port.

    Args:
        chip_variant (str): "lm629" or "lm628"
        axes (int): how many chips the board has (default: what the bridge reports)
        options (dict): port URL options, passed through as the URL's query (``fast_baud``,
            ``failsafe``, ``retries``, ...: whatever ``lm629 --port URL?...`` takes, checked
            by the transport that reads them when the driver activates)
    """

    bindings = {"port": {"SerialPort", "NetworkSerialPort"}}

    chip_variant = attr.ib(default="lm629", validator=attr.validators.instance_of(str))
    axes = attr.ib(default=None, validator=attr.validators.optional(attr.validators.instance_of(int)))
    options = attr.ib(factory=dict, validator=attr.validators.instance_of(dict))

    def __attrs_post_init__(self) -> None:
        super().__attrs_post_init__()
        self.board: lm629_host.Board | None = None

    @property
    def url(self) -> str:
        return port_url(self.port, self.options)

    def on_activate(self) -> None:
        self.board = lm629_host.open_board(self.url, axes=self.axes, chip=self.chip_variant)

    def on_deactivate(self) -> None:
        board, self.board = self.board, None
        if board is None:
            return
        try:
            for axis in board.axes:
                try:
                    moving = axis.is_moving()
                except LM629Error:
                    moving = True  # cannot tell: stop to be safe
                if moving:
                    emergency_stop(axis)
        finally:
            board.close()

    @Driver.check_active
    def chip(self, axis: int = 0, *, reset: bool = True) -> lm629_host.LM629:
        """The LM629 on chip select ``axis``, reset first (AN-706 4.4.1) unless ``reset=False``."""
        assert self.board is not None  # check_active: on_activate opened it
        chip = self.board.axis(axis)
        if reset:
            chip.reset()
        return chip

    @Driver.check_active
    def get_board(self, *, reset: bool = True) -> lm629_host.Board:
        """The Board (every chip select), all axes reset first unless ``reset=False``."""
        assert self.board is not None  # check_active: on_activate opened it
        if reset:
            self.board.reset()
        return self.board


__all__ = ["LM629Driver", "port_url"]
