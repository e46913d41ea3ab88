//! Field output for visualisation (`fields`, HDF5 + XDMF for ParaView), at the solver's edge.
//! The solver core (`latin`, `model`) does no I/O; this module only reads its types.

pub mod fields;
