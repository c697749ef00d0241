//! Stereo: census, SGM and the variational matchers against synthetic pairs with exact
//! disparity and the real pairs in ../shared/data.

#[path = "../common/mod.rs"]
mod common;
#[path = "../depth_support/mod.rs"]
mod depth_support;

mod sgm;
mod tgv;
