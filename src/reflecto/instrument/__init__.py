"""The virtual instrument of paper §4: devices, captures, calibration, slices.

::

    Device.builtin("ideal")            optics, LED layout, camera           device.py, optics.py, layout.py
    simulate_capture(brdf, device)     raw frames of one capture            simulate.py
    write_capture / read_capture       the capture folder (PNG + manifest)  capture.py
    simulate_calibration / calibrate   calibration captures → Calibration   simulate.py, calibrate.py
    extract_slices                     HDR merge, radiometry → Slices       hdr.py, slices.py

Which calibration reads a capture, and the whole capture→model path, are
:mod:`reflecto.workflow`'s.
"""

from .calibrate import Calibration, calibrate, load_calibration, nominal_calibration
from .capture import Capture, read_capture, write_capture
from .device import Camera, Device, load_device
from .layout import coverage, optimize_layout
from .simulate import simulate_calibration, simulate_capture
from .slices import Slices, extract_slices

__all__ = ["Calibration", "Camera", "Capture", "Device", "Slices", "calibrate", "coverage", "extract_slices",
           "load_calibration", "load_device", "nominal_calibration", "optimize_layout", "read_capture",
           "simulate_calibration", "simulate_capture", "write_capture"]
