//! Errors raised by environments and by the code that builds them.

/// Errors raised by environments: wrong buffer sizes, actions outside the action space, unknown
/// ids, settings out of range, saved states that do not fit.
#[derive(Debug, thiserror::Error)]
pub enum EnvError {
    /// The action buffer does not hold `num_envs x action_dim` values.
    #[error("expected {expected} action values (num_envs x action_dim), got {got}")]
    ActionLength {
        /// Values expected.
        expected: usize,
        /// Values received.
        got: usize,
    },
    /// A discrete action is not an integer index in `0..n`.
    #[error("environment {env}: action {value} is not a valid index in 0..{n}")]
    InvalidDiscreteAction {
        /// Index of the environment copy.
        env: usize,
        /// The offending value.
        value: f32,
        /// Number of discrete actions.
        n: usize,
    },
    /// The environment is built from a settings table of its training configuration, which the
    /// caller does not have (e.g. it only knows the id, from an exported policy).
    #[error("environment `{id}` needs the [{table}] table of its training configuration")]
    NeedsSettings {
        /// Environment id.
        id: String,
        /// Name of the settings table.
        table: String,
    },
    /// The environment id is not one the caller can build.
    #[error("unknown environment id `{id}` (expected one of: {known})", known = known.join(", "))]
    UnknownId {
        /// The id asked for.
        id: String,
        /// The ids that can be built.
        known: Vec<String>,
    },
    /// A saved state does not fit this environment.
    #[error("saved environment state does not fit {env}: {reason}")]
    StateMismatch {
        /// Environment id.
        env: String,
        /// What does not fit.
        reason: String,
    },
    /// `num_envs` must be at least one.
    #[error("num_envs must be >= 1, got {0}")]
    NoEnvs(usize),
    /// More copies than a registry builds (checked before anything is allocated).
    #[error("num_envs = {got}: expected at most {max} copies")]
    TooManyEnvs {
        /// The number asked for.
        got: usize,
        /// The most a task builds.
        max: usize,
    },
    /// A configuration value is outside its allowed range.
    #[error("{file}: key `{key}` = {value}: expected {expected}")]
    Config {
        /// The configuration file.
        file: String,
        /// Dotted key, e.g. `transport.control_hz`.
        key: String,
        /// The value found.
        value: String,
        /// The allowed range or values.
        expected: String,
    },
    /// A configuration could not be parsed (syntax, unknown or missing key, wrong type), or a
    /// file it names could not be used.
    #[error("{file}: {message}")]
    ConfigParse {
        /// The configuration file.
        file: String,
        /// What is wrong (names the key).
        message: String,
    },
    /// The simulator rejected a call (a fault of the environment, not of the input).
    #[error("simulator: {0}")]
    Simulator(String),
    /// An action value is not a finite number.
    #[error("environment {env}: action {index} is {value}, expected a finite number")]
    NonFiniteAction {
        /// Index of the environment copy.
        env: usize,
        /// Index within the action.
        index: usize,
        /// The offending value.
        value: f32,
    },
    /// A copy whose episode ended was stepped before being reset ([`crate::AutoresetMode::Disabled`]).
    #[error(
        "environment {env}: its episode ended and autoreset is disabled; reset it (reset mask) \
         before stepping"
    )]
    FinishedCopy {
        /// Index of the environment copy.
        env: usize,
    },
    /// A per-copy input (reset mask, seeds) does not hold one value per copy.
    #[error("expected one {what} value per environment copy ({expected}), got {got}")]
    BatchLength {
        /// What the values are.
        what: &'static str,
        /// Number of copies.
        expected: usize,
        /// Values received.
        got: usize,
    },
    /// The environment does not support what was asked (e.g. an autoreset mode).
    #[error("environment {env}: {what} is not supported")]
    Unsupported {
        /// Environment id.
        env: String,
        /// What was asked.
        what: String,
    },
}
