"""Property groups (Scene.gaussvdb, Object.gaussvdb, ViewLayer.gaussvdb) and what they hold."""
