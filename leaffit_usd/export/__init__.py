"""Non-USD deliverables of a LeafFit plant: glTF 2.0 / GLB (``export.gltf``) for game engines and
the web, and the Khronos validator wrapper the tests use (``export.validator``)."""
