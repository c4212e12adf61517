"""gmsh builders of the blank and the rigid forming tools."""
