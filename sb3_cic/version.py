"""The package version (saved with each model, see :func:`sb3_cic.common.save_util.package_version`)."""

__version__ = "0.1.0"
