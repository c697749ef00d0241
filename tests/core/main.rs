//! Core pipeline tests: analytic scenes with exact oracles (fusion, regularization, meshing),
//! the evaluation's statistics and outputs, and the pipeline on the real data in ../shared/data.

#[path = "../common/mod.rs"]
mod common;

mod analytic;
mod band_slices;
mod eval_analytic;
mod eval_output;
mod real_data;
mod rooms;
