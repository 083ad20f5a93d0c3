"""What the headless viewer (:mod:`lessons.tools.viewer`) needs and this machine may lack:
Xvfb, the viewer binary from ``rerun-sdk``, a Vulkan loader and driver (Mesa's lavapipe where
there is no GPU), libxkbcommon-x11. :func:`missing` lists what is absent; :func:`check_available`
raises :class:`ViewerUnavailable` naming it and the packages to install (APT_INSTALL)."""
from __future__ import annotations

import ctypes.util
import glob
import os
import shutil
import sys
from pathlib import Path

APT_INSTALL = ("apt-get install -y xvfb xauth mesa-vulkan-drivers libvulkan1 libxkbcommon-x11-0 "
               "libgl1 libegl1")
_ICD_DIRS = ("/usr/share/vulkan/icd.d", "/etc/vulkan/icd.d", "/usr/local/share/vulkan/icd.d")


class ViewerUnavailable(RuntimeError):
    """The headless viewer cannot run here; the message names what is missing and how to get it."""


def find_rerun(rerun_exe: str | os.PathLike | None = None) -> str | None:
    """The viewer binary: the one given, else the native binary inside the ``rerun_cli`` package
    (rather than its Python shim, which would sit between us and the viewer process), else
    ``rerun`` next to this Python or on PATH."""
    if rerun_exe is not None:
        return shutil.which(str(rerun_exe)) or (str(rerun_exe) if Path(rerun_exe).is_file() else None)
    if os.environ.get("RERUN_CLI_PATH") and Path(os.environ["RERUN_CLI_PATH"]).is_file():
        return os.environ["RERUN_CLI_PATH"]
    try:
        import rerun_cli
        native = Path(rerun_cli.__file__).with_name("rerun")
        if native.is_file() and os.access(native, os.X_OK):
            return str(native)
    except ImportError:
        pass
    beside = Path(sys.executable).with_name("rerun")
    if beside.is_file():
        return str(beside)
    return shutil.which("rerun")


def vulkan_icds() -> list[str]:
    """Installed Vulkan drivers (ICD manifests), from VK_ICD_FILENAMES/VK_DRIVER_FILES or the usual dirs."""
    listed = os.environ.get("VK_DRIVER_FILES") or os.environ.get("VK_ICD_FILENAMES")
    if listed:
        return [p for p in listed.split(os.pathsep) if Path(p).is_file()]
    return sorted(p for d in _ICD_DIRS for p in glob.glob(os.path.join(d, "*.json")))


def missing(rerun_exe: str | os.PathLike | None = None) -> list[str]:
    """What the headless viewer needs and this machine lacks (empty when all is there)."""
    lacks = []
    if shutil.which("Xvfb") is None:
        lacks.append("Xvfb (the virtual X server; Debian package xvfb)")
    if find_rerun(rerun_exe) is None:
        lacks.append("the rerun viewer binary (pip package rerun-sdk)")
    if ctypes.util.find_library("vulkan") is None:
        lacks.append("the Vulkan loader libvulkan.so.1 (Debian package libvulkan1)")
    if not vulkan_icds():
        lacks.append("a Vulkan driver: no ICD manifest in " + ", ".join(_ICD_DIRS)
                     + " (Mesa's software driver lavapipe: Debian package mesa-vulkan-drivers)")
    if ctypes.util.find_library("xkbcommon-x11") is None:
        lacks.append("libxkbcommon-x11 (Debian package libxkbcommon-x11-0)")
    return lacks


def check_available(rerun_exe: str | os.PathLike | None = None) -> None:
    lacks = missing(rerun_exe)
    if lacks:
        raise ViewerUnavailable("cannot run the Rerun viewer headless: missing " + "; ".join(lacks)
                                + f". Install with: {APT_INSTALL}")

