//! The multi-band image store: the file format (see ARCHITECTURE.md), its writer and
//! its reader. Everything above the input readers goes through this module.
