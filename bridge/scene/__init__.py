"""The world drawn: foxglove.SceneUpdate entities per category, and the semantic topics."""
