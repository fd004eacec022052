"""One drive's data path: the Pipeline that runs frames through the stages into the sinks,
perception's timing in log time, and the one place a drive is assembled."""

#: Scenes a second without ``--scene-rate`` (here, not in :mod:`bridge.pipeline.perception`: a
#: drive without a profile, which has no scene, never loads the profile's stages).
DEFAULT_SCENE_RATE = 20.0
