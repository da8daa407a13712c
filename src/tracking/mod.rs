//! The tracking thread's math (paper section III): the joint visual-inertial Gauss-Newton system
//! and its Schur-complement solution.

pub mod schur;

pub use schur::BlockSystem;
