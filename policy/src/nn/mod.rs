//! Network building blocks. Every piece is made of ops that candle can differentiate: candle 0.11's fused
//! `LayerNorm`, `softmax_last_dim` and `sdpa` have no backward and silently zero the gradients before them.

pub mod attention;
pub mod dit;
pub mod linear;
pub mod mlp;
pub mod norm;
pub mod resnet;
pub mod seeded_init;
pub mod spatial_softmax;
pub mod time_embed;
