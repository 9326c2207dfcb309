"""Scenes (geometry and decomposition) and their NGSolve assembly."""
from .assembly import LocalProblems, assemble, detect_templates
from .scene import Scene
from .structured import checkerboard, structured_square

__all__ = ["Scene", "LocalProblems", "assemble", "detect_templates", "structured_square", "checkerboard"]
