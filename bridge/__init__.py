"""tankviz: CAN buses → decoded signals → Foxglove scene, live and recorded as MCAP."""

#: The one place the version is written (pyproject.toml reads it: ``[tool.hatch.version]``);
#: a literal, so that no command pays for importlib.metadata at start-up.
__version__ = "0.1.0"
