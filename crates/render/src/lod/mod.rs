//! Level selection and loading: which tiles of which pyramid levels to draw for a
//! viewpoint (the paper's distance rule, or view-dependent selection under a point
//! budget), and a tile cache filled by worker threads under a memory budget.

pub mod cache;
pub mod point;
pub mod select;

pub use cache::{Extra, LoadedTile, Retries, TileCache, TileKey};
pub use select::{
    DEFAULT_BUDGET_CAP, LodMode, Selection, TileRef, budget_for_pixels, distance_level,
    level_count, select, select_clipped, select_region,
};
