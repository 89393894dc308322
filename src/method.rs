//! The synthesis methods by name (`--method`): what the command line, the memory guard,
//! the report and the synthesizers share. Its own module, below all of them, so that the
//! memory guard's per-method estimates need not import the synthesizers
//! ([`crate::synth`] re-exports it).

use serde::Serialize;

/// Synthesis method (`--method`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// Ying et al. 2001 §5: single pass, continues coherent patches (Ashikhmin).
    Coherent,
    /// Ying et al. 2001 §4: multiscale (Wei-Levoy), with k-coherence or ANN search.
    Multiscale,
    /// Paper 001 §5.2: patch sampling along the field (Liang et al.), joined by cuts.
    Patches,
    /// Paper 001 §4.3–4.4: texture optimisation (Kwatra et al.), multilevel.
    Optimise,
    /// Paper 002: jump maps (Zelinka & Garland), region growing over the texels.
    Jump,
    /// Paper 003: BTF synthesis with surface textons ([`crate::synth::Settings::btf`]; without a BTF
    /// sample, the example as a one-image sample). Not in [`Method::ALL`], the methods of
    /// plain examples.
    Textons,
}

impl Method {
    /// The method `synth` uses without `--method`: the one that keeps the example's
    /// structure best at good speed (docs/synthesis.md has the table it was chosen from).
    pub const DEFAULT: Method = Method::Optimise;

    /// Every method, in the order of docs/synthesis.md's table.
    pub const ALL: [Method; 5] = [
        Method::Coherent,
        Method::Multiscale,
        Method::Patches,
        Method::Optimise,
        Method::Jump,
    ];

    /// [`Method::ALL`] and textons: every name `--method` takes.
    pub const EVERY: [Method; 6] = [
        Method::Coherent,
        Method::Multiscale,
        Method::Patches,
        Method::Optimise,
        Method::Jump,
        Method::Textons,
    ];

    /// The orientation field a run of this method gets without `--orient`.
    ///
    /// Texture optimisation copies whole patches, so it shows the example as it is — upright
    /// bricks stay level only if the field keeps the example's up along the world's
    /// (`up`, +y); with guided final assembly its seams stay within the bar there
    /// (docs/synthesis.md, "The `up` field"). On a mostly level surface (terrain, a floor)
    /// `up` has no up to follow and draws contour rings, so the default is `upright`: `up`
    /// there only where the surface stands (`field::choice::upright`). The per-texel methods
    /// keep the smoothest field (`auto`): `up` raised patch sampling's seams on the double
    /// torus (1.31) and gains them nothing measured.
    pub fn default_orientation(self) -> crate::field::Orientation {
        match self {
            Method::Optimise => crate::field::Orientation::Upright(glam::DVec3::Y),
            _ => crate::field::Orientation::Auto,
        }
    }

    /// Why this method cannot take a BTF sample, if it cannot — one message for the
    /// command line, which checks before any work, and for [`crate::synth::synthesize`],
    /// which checks for library callers.
    pub fn btf_refusal(self) -> Option<&'static str> {
        match self {
            Method::Multiscale => Some(
                "with a BTF sample, --method multiscale would match its default image only: use --method textons (multiscale over every image) or optimise, patches, coherent, jump (every image in appearance space)",
            ),
            _ => None,
        }
    }

    /// One line on what the method does: `--method`'s help beside each name.
    pub fn summary(self) -> &'static str {
        match self {
            Method::Coherent => "Single pass, copies coherent patches (000 §5): the fast preview",
            Method::Multiscale => "Gaussian pyramid, two passes per level (000 §4)",
            Method::Patches => {
                "Whole example patches along the field, joined by minimum-error cuts (001 §5.2)"
            }
            Method::Optimise => {
                "Texture optimisation: EM over overlapping surface patches, multilevel (001 §4)"
            }
            Method::Jump => {
                "Jump maps: region growing, continuations and weighted jumps, no matching (002)"
            }
            Method::Textons => {
                "BTF synthesis with surface textons: every image of --btf at once, multiscale over textons (003). The other methods but multiscale take a BTF too, matching every image in appearance space"
            }
        }
    }

    /// The name used on the command line and in report.json.
    pub fn name(self) -> &'static str {
        match self {
            Method::Coherent => "coherent",
            Method::Multiscale => "multiscale",
            Method::Patches => "patches",
            Method::Optimise => "optimise",
            Method::Jump => "jump",
            Method::Textons => "textons",
        }
    }
}

impl std::str::FromStr for Method {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        Method::EVERY
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| {
                let names: Vec<_> = Method::EVERY.iter().map(|m| m.name()).collect();
                format!(
                    "unknown method '{s}' (expected one of {})",
                    names.join(", ")
                )
            })
    }
}

/// `--method`'s values: [`Method::EVERY`], each [`Method::name`] with [`Method::summary`] as
/// help. Here rather than as a second enum in the command line's module, which had to be
/// kept in step with this one by hand.
impl clap::ValueEnum for Method {
    fn value_variants<'a>() -> &'a [Self] {
        &Method::EVERY
    }

    fn to_possible_value(&self) -> Option<clap::builder::PossibleValue> {
        Some(clap::builder::PossibleValue::new(self.name()).help(self.summary()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::ValueEnum;

    /// The command line offers every method, textons included, under the name report.json
    /// and `FromStr` use, each with a line of help.
    #[test]
    fn command_line_values_are_the_names() {
        let values = Method::value_variants();
        assert_eq!(values.len(), Method::ALL.len() + 1);
        for m in Method::EVERY {
            assert!(values.contains(&m));
            let v = m.to_possible_value().expect("not hidden");
            assert_eq!(v.get_name(), m.name());
            assert!(v.get_help().is_some_and(|h| !h.to_string().is_empty()));
            assert_eq!(Method::from_str(m.name(), false), Ok(m));
            assert_eq!(m.name().parse::<Method>(), Ok(m));
        }
    }
}
