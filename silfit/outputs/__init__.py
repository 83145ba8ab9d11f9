"""Outputs for other tools: meshes in an upright world frame (:mod:`.export`: GLB, PLY, an animated
glTF of a video) and a static HTML gallery of many fits (:mod:`.report`)."""
