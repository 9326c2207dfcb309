"""Scenes (geometry and decomposition) and their NGSolve assembly."""
from .assembly import LocalProblems, assemble, detect_templates
from .scene import Scene
from .structured import checkerboard, structured_square
from .unstructured import scene_from_mesh, unstructured_scene

__all__ = ["Scene", "LocalProblems", "assemble", "detect_templates", "structured_square", "checkerboard",
           "unstructured_scene", "scene_from_mesh"]
