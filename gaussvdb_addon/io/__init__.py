"""The add-on's data on disk: the point-cloud schema (schema.py), the datablocks an import
creates (datablocks.py) and the upgrade of files written by older versions (versioning.py)."""
