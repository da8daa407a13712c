//! Mapping (paper section IV): the semidense inverse-depth mapper that feeds tracking.

pub mod semidense;
