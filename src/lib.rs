
pub mod field;
