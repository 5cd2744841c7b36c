"""The pyusb side of the simulated camera: a ``usb.backend.IBackend`` over SimCameras.

    backend = SimBackend(SimCamera(events_source(events)))
    dev = usb.core.find(idVendor=0x04B4, idProduct=0x00F4, backend=backend)

The device has the camera's descriptors (one configuration, interface 0, bulk IN endpoint
0x81 with wMaxPacketSize 512) and goes through pyusb's own Device, ctrl_transfer and read
code as it would against libusb.  pyusb conventions kept: bulk reads fill the caller's
``array('B')`` and return the byte count; a vanished device raises USBError errno 19 on
every call through its old handle and leaves the enumeration until it re-enumerates (new
address, unconfigured).
"""
from __future__ import annotations

import errno

import usb.backend
import usb.util

from .. import camera as camusb
from .device import MAX_PACKET, SimCamera, usb_error


class _Desc:
    def __init__(self, **kw):
        self.__dict__.update(kw)


class SimBackend(usb.backend.IBackend):
    """pyusb backend over one or more :class:`SimCamera` devices."""

    def __init__(self, *cameras: SimCamera, vid: int = camusb.CCAM_VID, pid: int = camusb.CCAM_PID):
        super().__init__()
        self.cameras = list(cameras)
        self.vid, self.pid = vid, pid

    # ---- descriptors ---------------------------------------------------------------
    def enumerate_devices(self):
        for cam in self.cameras:
            if cam.present():
                yield cam

    def get_device_descriptor(self, dev):
        return _Desc(bLength=18, bDescriptorType=1, bcdUSB=0x0200, bDeviceClass=0xFF,
                     bDeviceSubClass=0, bDeviceProtocol=0, bMaxPacketSize0=64,
                     idVendor=self.vid, idProduct=self.pid, bcdDevice=0x0100, iManufacturer=0,
                     iProduct=0, iSerialNumber=0, bNumConfigurations=1, address=dev.address,
                     bus=dev.bus, port_number=1, port_numbers=(1,), speed=usb.util.SPEED_HIGH)

    def get_configuration_descriptor(self, dev, config):
        if config != 0:
            raise IndexError(f"configuration index {config} out of range")
        return _Desc(bLength=9, bDescriptorType=2, wTotalLength=25, bNumInterfaces=1,
                     bConfigurationValue=1, iConfiguration=0, bmAttributes=0x80, bMaxPower=250,
                     extra_descriptors=[])

    def get_interface_descriptor(self, dev, intf, alt, config):
        if (intf, alt, config) != (0, 0, 0):
            raise IndexError(f"interface {intf} alt {alt} of configuration {config} out of range")
        return _Desc(bLength=9, bDescriptorType=4, bInterfaceNumber=0, bAlternateSetting=0,
                     bNumEndpoints=1, bInterfaceClass=0xFF, bInterfaceSubClass=0,
                     bInterfaceProtocol=0, iInterface=0, extra_descriptors=[])

    def get_endpoint_descriptor(self, dev, ep, intf, alt, config):
        if (ep, intf, alt, config) != (0, 0, 0, 0):
            raise IndexError(f"endpoint {ep} out of range")
        return _Desc(bLength=7, bDescriptorType=5, bEndpointAddress=camusb.EP_IN,
                     bmAttributes=0x02, wMaxPacketSize=MAX_PACKET, bInterval=0, bRefresh=0,
                     bSynchAddress=0, extra_descriptors=[])

    # ---- handles ---------------------------------------------------------------------
    def _cam(self, h) -> SimCamera:
        cam, gen = h
        if not cam.connected or cam.generation != gen:
            raise usb_error(errno.ENODEV, "No such device (it may have been disconnected)")
        return cam

    def open_device(self, dev):
        if not dev.present():
            raise usb_error(errno.ENODEV, "No such device (it may have been disconnected)")
        return (dev, dev.generation)

    def close_device(self, dev_handle):
        pass

    def set_configuration(self, dev_handle, config_value):
        cam = self._cam(dev_handle)
        if config_value not in (0, 1):
            raise usb_error(errno.EINVAL, f"Invalid parameter (configuration {config_value})")
        cam.configuration = config_value

    def get_configuration(self, dev_handle):
        return self._cam(dev_handle).configuration

    def set_interface_altsetting(self, dev_handle, intf, altsetting):
        self._cam(dev_handle)
        if (intf, altsetting) != (0, 0):
            raise usb_error(errno.EINVAL, "Invalid parameter (alternate setting)")

    def claim_interface(self, dev_handle, intf):
        cam = self._cam(dev_handle)
        if intf != 0:
            raise usb_error(errno.ENOENT, f"Entity not found (interface {intf})")
        cam.claimed.add(intf)

    def release_interface(self, dev_handle, intf):
        cam = self._cam(dev_handle)
        cam.claimed.discard(intf)

    # ---- transfers -------------------------------------------------------------------
    def bulk_read(self, dev_handle, ep, intf, buff, timeout):
        cam = self._cam(dev_handle)
        if ep != camusb.EP_IN:
            raise usb_error(errno.EPIPE, f"Pipe error (no IN endpoint 0x{ep:02X})")
        if 0 not in cam.claimed:
            raise usb_error(errno.EBUSY, "Resource busy (interface 0 not claimed)")
        if cam.configuration != 1:
            raise usb_error(errno.EIO, "Input/Output Error (device not configured)")
        if timeout is None or timeout <= 0:
            raise ValueError("simulated camera: bulk reads need a finite timeout")
        return cam.bulk_read(buff, timeout)

    def bulk_write(self, dev_handle, ep, intf, data, timeout):
        self._cam(dev_handle)
        raise usb_error(errno.EPIPE, f"Pipe error (no OUT endpoint 0x{ep:02X})")

    def ctrl_transfer(self, dev_handle, bmRequestType, bRequest, wValue, wIndex, data, timeout):
        cam = self._cam(dev_handle)
        with cam.lock:
            return cam.control(bmRequestType, bRequest, wValue, wIndex, data)

    def clear_halt(self, dev_handle, ep):
        self._cam(dev_handle).halted = False

    def reset_device(self, dev_handle):
        cam = self._cam(dev_handle)
        cam._reset_state()

    def is_kernel_driver_active(self, dev_handle, intf):
        self._cam(dev_handle)
        return False

    def detach_kernel_driver(self, dev_handle, intf):
        self._cam(dev_handle)

    def attach_kernel_driver(self, dev_handle, intf):
        self._cam(dev_handle)
