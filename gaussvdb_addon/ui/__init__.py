"""Panels, menus and lists of the properties editor."""
