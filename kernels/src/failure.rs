//! Why a member stopped.

/// Why a member stopped (a code, so the GPU can store it in a u32).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u32)]
pub enum Failure {
    None = 0,
    /// The step fell below dt_min while every trial gave a non-finite value or opened a gap
    /// beyond the MAX_OPENING safeguard.
    Inadmissible = 1,
    /// The step fell below dt_min while the error estimate stayed above the tolerance.
    ErrorTooLarge = 2,
    /// The step fell below dt_min while every trial raised the energy beyond the forcing's work.
    EnergyRose = 3,
    /// The forcing is not finite at a particle (detail: its position).
    Forcing = 4,
    /// The repulsion (rho/rho*)^gamma overflows at a gap (detail: the density ratio).
    Repulsion = 5,
    /// The last `STALL_WINDOW` attempts advanced the member too little to reach the next output
    /// time within 1e12 attempts (`control::STALL_PACE`), every step above the step floor.
    Stalled = 6,
}

impl Failure {
    pub fn from_code(code: u32) -> Failure {
        match code {
            0 => Failure::None,
            1 => Failure::Inadmissible,
            2 => Failure::ErrorTooLarge,
            3 => Failure::EnergyRose,
            4 => Failure::Forcing,
            5 => Failure::Repulsion,
            _ => Failure::Stalled,
        }
    }
}
