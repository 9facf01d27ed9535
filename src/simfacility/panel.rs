//! The simulated panel's colour channels: three primaries cut from the
//! configured white spectrum by smooth band windows, each channel's tone
//! curve (drive → relative emission: a power law with a linear toe near
//! black and a soft shoulder near the top), and crosstalk between the
//! channels' emissions. A grey drive level x sets R = G = B = x.
//!
//! Windows (λ in nm, edges e₁ < e₂, width s, σ the logistic function):
//!
//! w_B = 1 − σ((λ − e₁)/s),  w_R = σ((λ − e₂)/s),  w_G = 1 − w_B − w_R
//!
//! so w_R + w_G + w_B = 1 and full white (every E_c = 1) is the white
//! spectrum. Tone curve of channel c (γ_c = gamma + channel_gamma_delta_c):
//!
//! g_c(x) = (x^γ_c + toe_c · x · e^(−x / toe_width)) · (1 − shoulder_c · x⁶),
//! T_c(x) = g_c(x) / g_c(1)
//!
//! and emissions E = M T with M_cc = 1 − 2k, M_cc' = k (k = `crosstalk`):
//! each channel leaks a fraction k of its light into each other channel's
//! primary, so full white still has E_c = 1.

use super::config::ScreenTruth;
use crate::error::{Error, Result};

/// The three channels' windows and tone curves.
#[derive(Debug, Clone, PartialEq)]
pub struct Panel {
    /// Window edges [blue|green, green|red], m.
    edges: [f64; 2],
    /// Window edge width, m.
    width: f64,
    gammas: [f64; 3],
    toe: [f64; 3],
    toe_width: f64,
    shoulder: [f64; 3],
    crosstalk: f64,
}

/// Channel order: red, green, blue.
pub const CHANNELS: [&str; 3] = ["red", "green", "blue"];

impl Panel {
    /// From the screen's configuration; a tone curve that decreases
    /// somewhere on the drive grid is an error naming `screen.shoulder`.
    pub fn from_config(c: &ScreenTruth) -> Result<Panel> {
        let panel = Panel {
            edges: [c.primary_edges_nm[0] * 1e-9, c.primary_edges_nm[1] * 1e-9],
            width: c.primary_edge_width_nm * 1e-9,
            gammas: [0, 1, 2].map(|k| c.gamma + c.channel_gamma_delta[k]),
            toe: c.toe,
            toe_width: c.toe_width,
            shoulder: c.shoulder,
            crosstalk: c.crosstalk,
        };
        let n = c.levels() - 1;
        for (ch, name) in CHANNELS.iter().enumerate() {
            let mut last = 0.0;
            for level in 0..=n {
                let t = panel.tone(ch, level as f64 / n as f64);
                if !(t.is_finite() && t >= last) {
                    return Err(Error::invalid(
                        "screen.shoulder",
                        format!(
                            "the {name} channel's tone curve decreases at level {level}: reduce shoulder or toe"
                        ),
                    ));
                }
                last = t;
            }
        }
        Ok(panel)
    }

    /// Window of channel `ch` (0 red, 1 green, 2 blue) at `wavelength` [m].
    pub fn window(&self, ch: usize, wavelength: f64) -> f64 {
        let sigma = |edge: f64| 1.0 / (1.0 + (-(wavelength - edge) / self.width).exp());
        let blue = 1.0 - sigma(self.edges[0]);
        let red = sigma(self.edges[1]);
        match ch {
            0 => red,
            1 => 1.0 - blue - red,
            _ => blue,
        }
    }

    fn raw_tone(&self, ch: usize, x: f64) -> f64 {
        let toe = self.toe[ch] * x * (-x / self.toe_width).exp();
        (x.powf(self.gammas[ch]) + toe) * (1.0 - self.shoulder[ch] * x.powi(6))
    }

    /// T_c(x): relative emission of channel `ch` at drive x ∈ [0, 1].
    pub fn tone(&self, ch: usize, x: f64) -> f64 {
        self.raw_tone(ch, x) / self.raw_tone(ch, 1.0)
    }

    /// E(x): the channels' emissions at grey drive x, crosstalk included.
    pub fn emissions(&self, x: f64) -> [f64; 3] {
        let t = [0, 1, 2].map(|c| self.tone(c, x));
        let k = self.crosstalk;
        let sum: f64 = t.iter().sum();
        t.map(|tc| (1.0 - 2.0 * k) * tc + k * (sum - tc))
    }
}
