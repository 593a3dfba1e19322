pub mod bench;
pub mod bundle;
pub mod free_energy;
pub mod import;
pub mod infer;
pub mod init;
pub mod simulate;
pub mod train;
