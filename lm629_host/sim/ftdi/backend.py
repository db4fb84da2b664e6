"""A pyusb backend (``usb.backend.IBackend``) that presents emulated FT232H devices.

This is the seam below pyftdi: pyftdi talks to pyusb's ``usb.core.Device``, which talks to a
backend; real hardware is reached through pyusb's libusb1 backend, the emulated FT232H through
this one.  Everything above it (pyusb's descriptor parsing and resource management, pyftdi's
open sequence, chunking and modem-status stripping, the project's FTDI transport) is the real
code.

Two ways in:

* ``usb.core.find(backend=EmulatedBackend([device]), idVendor=0x0403)`` gives a pyusb device
  for ``Ftdi.open_mpsse_from_device`` (``sim+ftdi://`` does this: no global state touched);
* this module has a ``get_backend()`` like pyusb's own backend modules, returning the shared
  :data:`SHARED` backend, so that a test can put ``"lm629_host.sim.ftdi.backend"`` into
  ``pyftdi.usbtools.UsbTools.BACKENDS`` and run pyftdi's URL lookup (``ftdi://ftdi:232h:SN/1``)
  and device listing on emulated devices.  ``SHARED.libusb_present = False`` makes
  ``get_backend()`` answer None, as pyusb's libusb1 module does when the library is missing.

Faults for the error-message tests, where libusb reports them: ``device.open_error = 13``
(EACCES: no permission to open the device node; pyusb then cannot even read the serial
number), ``device.claim_error = 16`` (EBUSY: another program or a kernel driver holds the
interface; the first bulk transfer fails).
"""

from __future__ import annotations

import array
import errno
from types import SimpleNamespace

import usb.backend
import usb.core
from usb.core import USBError

from lm629_host.sim.ftdi.device import BufferFull, EmulatedFT232H

#: endpoint addresses of the FT232H's one interface
EP_IN = 0x81
EP_OUT = 0x02

_STRINGS = {1: "manufacturer", 2: "product", 3: "serial"}


def _device_descriptor(dev: EmulatedFT232H) -> SimpleNamespace:
    return SimpleNamespace(
        bLength=18, bDescriptorType=1, bcdUSB=0x0200, bDeviceClass=0, bDeviceSubClass=0,
        bDeviceProtocol=0, bMaxPacketSize0=64, idVendor=dev.vendor_id, idProduct=dev.product_id,
        bcdDevice=dev.bcd_device, iManufacturer=1, iProduct=2, iSerialNumber=3,
        bNumConfigurations=1, address=dev.address, bus=dev.bus, port_number=1,
        port_numbers=(1,), speed=3)  # speed 3: high speed


def _config_descriptor() -> SimpleNamespace:
    return SimpleNamespace(
        bLength=9, bDescriptorType=2, wTotalLength=32, bNumInterfaces=1, bConfigurationValue=1,
        iConfiguration=0, bmAttributes=0x80, bMaxPower=45, extra_descriptors=b"")


def _interface_descriptor() -> SimpleNamespace:
    return SimpleNamespace(
        bLength=9, bDescriptorType=4, bInterfaceNumber=0, bAlternateSetting=0, bNumEndpoints=2,
        bInterfaceClass=0xFF, bInterfaceSubClass=0xFF, bInterfaceProtocol=0xFF, iInterface=2,
        extra_descriptors=b"")


def _endpoint_descriptor(address: int) -> SimpleNamespace:
    return SimpleNamespace(
        bLength=7, bDescriptorType=5, bEndpointAddress=address, bmAttributes=0x02,
        wMaxPacketSize=512, bInterval=0, bRefresh=0, bSynchAddress=0, extra_descriptors=b"")


class _Handle:
    def __init__(self, dev: EmulatedFT232H) -> None:
        self.dev = dev
        self.configuration = 0


class EmulatedBackend(usb.backend.IBackend):
    """pyusb backend over a list of :class:`EmulatedFT232H`."""

    def __init__(self, devices: list[EmulatedFT232H] | None = None) -> None:
        self.devices: list[EmulatedFT232H] = list(devices or [])
        self.libusb_present = True

    # enumeration and descriptors
    def enumerate_devices(self):
        return iter(list(self.devices))

    def get_parent(self, dev):
        return None

    def get_device_descriptor(self, dev):
        return _device_descriptor(dev)

    def get_configuration_descriptor(self, dev, config):
        if config != 0:
            raise IndexError(f"configuration {config}")
        return _config_descriptor()

    def get_interface_descriptor(self, dev, intf, alt, config):
        if (intf, alt, config) != (0, 0, 0):
            raise IndexError(f"interface {intf}/{alt}")
        return _interface_descriptor()

    def get_endpoint_descriptor(self, dev, ep, intf, alt, config):
        if ep not in (0, 1):
            raise IndexError(f"endpoint {ep}")
        return _endpoint_descriptor((EP_IN, EP_OUT)[ep])

    # handles and configuration
    def open_device(self, dev):
        code = getattr(dev, "open_error", None)
        if code:
            raise USBError(f"[Errno {code}] {errno.errorcode.get(code, code)}", code, code)
        return _Handle(dev)

    def close_device(self, dev_handle):
        pass

    def set_configuration(self, dev_handle, config_value):
        dev_handle.configuration = config_value

    def get_configuration(self, dev_handle):
        return dev_handle.configuration

    def set_interface_altsetting(self, dev_handle, intf, altsetting):
        pass

    def claim_interface(self, dev_handle, intf):
        code = getattr(dev_handle.dev, "claim_error", None)
        if code:
            raise USBError(f"[Errno {code}] {errno.errorcode.get(code, code)}", code, code)

    def release_interface(self, dev_handle, intf):
        pass

    def is_kernel_driver_active(self, dev_handle, intf):
        return False

    def detach_kernel_driver(self, dev_handle, intf):
        pass

    def attach_kernel_driver(self, dev_handle, intf):
        pass

    def clear_halt(self, dev_handle, ep):
        pass

    def reset_device(self, dev_handle):
        dev_handle.dev.control_out(0, 0, 0, b"")

    # transfers
    def bulk_write(self, dev_handle, ep, intf, data, timeout):
        if ep != EP_OUT:
            raise USBError(f"bulk write to endpoint {ep:#x}", errno.EINVAL, errno.EINVAL)
        try:
            return dev_handle.dev.bulk_out(bytes(data))
        except BufferFull as exc:  # libusb: the device NAKed the transfer until the timeout
            raise usb.core.USBTimeoutError(f"[Errno 110] Operation timed out ({exc})",
                                           errno.ETIMEDOUT, -7) from None

    def bulk_read(self, dev_handle, ep, intf, buff, timeout):
        if ep != EP_IN:
            raise USBError(f"bulk read from endpoint {ep:#x}", errno.EINVAL, errno.EINVAL)
        data = dev_handle.dev.bulk_in(len(buff) * buff.itemsize)
        buff[:len(data)] = array.array("B", data)
        return len(data)

    def ctrl_transfer(self, dev_handle, bmRequestType, bRequest, wValue, wIndex, data, timeout):  # noqa: N803 - pyusb names the parameters
        dev: EmulatedFT232H = dev_handle.dev
        if bmRequestType & 0x60 == 0x00:  # standard request
            if bRequest == 6 and wValue >> 8 == 3:  # GET_DESCRIPTOR, string
                index = wValue & 0xFF
                if index == 0:
                    raw = bytes((4, 3, 0x09, 0x04))  # language: en-US
                else:
                    text = getattr(dev, _STRINGS.get(index, ""), "") or ""
                    enc = text.encode("utf-16-le")
                    raw = bytes((2 + len(enc), 3)) + enc
                n = min(len(raw), len(data))
                data[:n] = array.array("B", raw[:n])
                return n
            if bmRequestType & 0x80:
                return 0
            return len(data)
        if bmRequestType & 0x80:  # vendor IN
            answer = dev.control_in(bRequest, wValue, wIndex, len(data))
            data[:len(answer)] = array.array("B", answer)
            return len(answer)
        return dev.control_out(bRequest, wValue, wIndex, bytes(data))


#: the backend ``get_backend()`` returns (see the module docstring)
SHARED = EmulatedBackend()


def get_backend(find_library=None):
    """pyusb's backend-module entry point: the shared emulated backend, or None when it plays a
    machine without libusb."""
    return SHARED if SHARED.libusb_present else None
