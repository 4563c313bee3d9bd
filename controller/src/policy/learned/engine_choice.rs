//! Which engine runs a policy's networks, and the report of what ran: the compiled engine
//! with its instruction set, or tract, and why tract where the engine was asked for.

use crate::policy::engine::Isa;

/// Which engine runs a policy's networks.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Engine {
    /// The compiled engine (allocation-free steps), tract where it cannot lower a network.
    #[default]
    Compiled,
    /// tract for every network (the reference the engine is checked against).
    Tract,
}

impl Engine {
    pub fn name(self) -> &'static str {
        match self {
            Self::Compiled => "compiled",
            Self::Tract => "tract",
        }
    }
}

impl std::str::FromStr for Engine {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, Self::Err> {
        match text {
            "compiled" => Ok(Self::Compiled),
            "tract" => Ok(Self::Tract),
            _ => Err(format!("unknown engine {text:?}; compiled or tract")),
        }
    }
}

/// How to load a policy: the engine, and for the compiled one the instruction set (the
/// widest this CPU runs when `None`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct EngineOptions {
    pub engine: Engine,
    pub isa: Option<Isa>,
}

impl EngineOptions {
    /// The instruction set the compiled engine runs: the one named, else the widest this CPU
    /// has; none for tract, which has none to choose.
    pub fn instruction_set(&self) -> Option<Isa> {
        (self.engine == Engine::Compiled).then(|| self.isa.unwrap_or_else(Isa::detect))
    }
}

/// What runs a loaded policy's networks.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct EngineReport {
    /// The compiled engine with this instruction set, or tract (`None`).
    pub compiled: Option<Isa>,
    /// Why tract runs a network although the compiled engine was asked for.
    pub fallback: Option<String>,
    /// The multiply-adds of the network one step runs, where the compiled engine runs it
    /// (its count of a lowered plan; tract's plan is not counted).
    pub multiply_adds: Option<u64>,
    /// Whether the compiled engine runs a convolution by Winograd's minimal filtering, which
    /// rounds differently from the direct sum (named in the report: a closed loop's goal
    /// count belongs to the arithmetic that measured it).
    pub winograd: bool,
    /// Whether the compiled engine runs int8 steps (an int8 policy's QDQ network lowered to
    /// integer kernels): its multiply-adds are then mostly 8-bit ones.
    pub int8: bool,
}

impl std::fmt::Display for EngineReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match (&self.compiled, &self.fallback) {
            (Some(isa), _) if self.int8 => write!(f, "compiled ({isa}, int8)"),
            (Some(isa), _) if self.winograd => write!(f, "compiled ({isa}, winograd)"),
            (Some(isa), _) => write!(f, "compiled ({isa})"),
            (None, Some(why)) => write!(f, "tract (the compiled engine cannot run it: {why})"),
            (None, None) => f.write_str("tract"),
        }
    }
}
