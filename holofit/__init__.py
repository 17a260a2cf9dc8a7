"""holofit: fast, exact holographic tracking of non-spherical colloids."""

__version__ = "0.1.0"
