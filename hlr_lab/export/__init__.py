"""Exports of fitted materials on the mesh: OBJ + MTL, glTF 2.0 (GLB) and a Mitsuba 3 scene.

Every export splits the mesh by region (one material each) and stays in the mesh's own frame and units.
A region whose specular was not measured is exported diffuse-only (no highlight), never with guesses.
"""
