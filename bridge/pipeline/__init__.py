"""One drive's data path: the Pipeline that runs frames through the stages into the sinks,
perception's timing in log time, and the one place a drive is assembled."""
