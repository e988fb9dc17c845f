//! Observation and action spaces with names, units and bounds.

/// Whether a space holds real values or a choice among `n` options.
#[derive(Debug, Clone, PartialEq)]
pub enum SpaceKind {
    /// Real values within `[low, high]` per dimension.
    Continuous,
    /// One index in `0..n` (stored as one f32 value in action buffers).
    Discrete {
        /// Number of choices.
        n: usize,
    },
}

/// A space: one entry per dimension in `names`, `units`, `low` and `high`.
#[derive(Debug, Clone, PartialEq)]
pub struct Space {
    /// Continuous or discrete.
    pub kind: SpaceKind,
    /// What each dimension means, e.g. `cart_position`.
    pub names: Vec<String>,
    /// SI unit of each dimension (`m`, `rad/s`, `N m`, `index`, ...).
    pub units: Vec<String>,
    /// Lower bound per dimension (`f32::MIN` where unbounded).
    pub low: Vec<f32>,
    /// Upper bound per dimension (`f32::MAX` where unbounded).
    pub high: Vec<f32>,
}

impl Space {
    /// A continuous box from `(name, unit, low, high)` rows.
    pub fn continuous(dims: &[(&str, &str, f32, f32)]) -> Self {
        Self {
            kind: SpaceKind::Continuous,
            names: dims.iter().map(|d| d.0.to_string()).collect(),
            units: dims.iter().map(|d| d.1.to_string()).collect(),
            low: dims.iter().map(|d| d.2).collect(),
            high: dims.iter().map(|d| d.3).collect(),
        }
    }

    /// A discrete choice among `n` options described by `name`.
    pub fn discrete(name: &str, n: usize) -> Self {
        Self {
            kind: SpaceKind::Discrete { n },
            names: vec![name.to_string()],
            units: vec!["index".to_string()],
            low: vec![0.0],
            high: vec![n.saturating_sub(1) as f32],
        }
    }

    /// Number of values per environment copy (1 for a discrete space).
    pub fn dim(&self) -> usize {
        self.names.len()
    }
}

/// Everything a trainer needs to know about an environment.
#[derive(Debug, Clone, PartialEq)]
pub struct EnvSpec {
    /// Gymnasium-style id, e.g. `CartPole-v1`.
    pub id: String,
    /// Observation space of the actor: what the policy acts on (on a real robot, what the cell
    /// measures).
    pub observation: Space,
    /// Observation space of the critic when it differs from the actor's (RSL-RL's observation
    /// groups: the critic may see privileged simulator state); `None`: the critic sees
    /// [`EnvSpec::observation`].
    pub critic_observation: Option<Space>,
    /// Action space.
    pub action: Space,
    /// Episodes are truncated after this many steps.
    pub max_episode_steps: usize,
}

impl EnvSpec {
    /// Width of the critic's observation: [`EnvSpec::critic_observation`]'s, or the actor's.
    pub fn critic_obs_dim(&self) -> usize {
        self.critic_observation
            .as_ref()
            .map_or(self.observation.dim(), Space::dim)
    }

    /// Whether the critic has its own observation group.
    pub fn is_asymmetric(&self) -> bool {
        self.critic_observation.is_some()
    }
}
