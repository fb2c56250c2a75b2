"""Rendering: meshes and point clouds."""
