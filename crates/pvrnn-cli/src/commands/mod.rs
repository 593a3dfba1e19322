pub mod bench;
pub mod free_energy;
pub mod infer;
pub mod init;
pub mod train;
