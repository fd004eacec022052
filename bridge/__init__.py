"""tankviz: CAN buses → decoded signals → Foxglove scene, live and recorded as MCAP."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("tankviz")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0.0.0+source"
