//! The `Reconstructor`: wires readers, depth, fusion, regularisation, meshing and evaluation.
