//! Inference between scans: the data-driven patch prior compiled into flash, the 3 × 3 patch
//! bit layout, the forward sensor model, the ray store and the bounded, border-conditioned patch
//! Gibbs sampler (Merali & Barfoot, Algorithm 1). Imports [`crate::types`] and, where the
//! sampler follows the mapper's updates, [`crate::map`].

pub mod forward_model;
pub mod gibbs;
pub mod patch;
pub mod prior;
pub mod ray_store;
