//! Passwords kept as salted PBKDF2-HMAC-SHA256 digests: people choose OPC UA passwords, so the
//! digest must be slow to search, unlike the dashboard's random tokens.
//!
//! Must not log or keep a password it was given.

use std::fmt::Write as _;
use std::num::NonZeroU32;

use ring::pbkdf2;

/// The scheme written before a stored digest.
const SCHEME: &str = "pbkdf2-sha256";
/// Bytes of a digest.
const DIGEST_LEN: usize = 32;
/// The fewest iterations taken: fewer would make a stolen configuration cheap to search.
const MIN_ITERATIONS: u32 = 1_000;
/// Iterations of a digest made here: OWASP's figure for PBKDF2-HMAC-SHA256 (its Password Storage
/// Cheat Sheet), paid once per sign-in.
pub const ITERATIONS: u32 = 600_000;
/// Bytes of a salt made here.
const SALT_LEN: usize = 16;

/// A password's stored digest: `pbkdf2-sha256:<iterations>:<salt, hex>:<digest, hex>`.
#[derive(Clone, PartialEq, Eq)]
pub struct PasswordHash {
    iterations: NonZeroU32,
    salt: Vec<u8>,
    digest: [u8; DIGEST_LEN],
}

impl std::fmt::Debug for PasswordHash {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PasswordHash")
            .field("iterations", &self.iterations)
            .finish_non_exhaustive()
    }
}

/// Why a stored digest cannot be read.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
#[error(
    "'{0}' is not pbkdf2-sha256:<iterations, at least 1000>:<salt, hex, 8 bytes or more>:<digest, hex, 32 bytes>"
)]
pub struct PasswordHashError(String);

impl PasswordHash {
    /// A stored digest read.
    pub fn parse(text: &str) -> Result<Self, PasswordHashError> {
        let error = || {
            // The digest is not secret, but a mistyped password pasted here would be.
            let shown: String = text.chars().take(SCHEME.len() + 1).collect();
            PasswordHashError(format!("{shown}…"))
        };
        let mut parts = text.split(':');
        if parts.next() != Some(SCHEME) {
            return Err(error());
        }
        let iterations = parts
            .next()
            .and_then(|part| part.parse::<u32>().ok())
            .filter(|&iterations| iterations >= MIN_ITERATIONS)
            .and_then(NonZeroU32::new)
            .ok_or_else(error)?;
        let salt = parts
            .next()
            .and_then(from_hex)
            .filter(|salt| salt.len() >= 8)
            .ok_or_else(error)?;
        let digest = parts
            .next()
            .and_then(from_hex)
            .and_then(|digest| <[u8; DIGEST_LEN]>::try_from(digest).ok())
            .ok_or_else(error)?;
        if parts.next().is_some() {
            return Err(error());
        }
        Ok(Self {
            iterations,
            salt,
            digest,
        })
    }

    /// `password`'s digest with a fresh random salt and [`ITERATIONS`]; `None` only when the
    /// system's random source fails.
    #[must_use]
    pub fn of(password: &str) -> Option<Self> {
        use ring::rand::SecureRandom as _;
        let mut salt = vec![0_u8; SALT_LEN];
        ring::rand::SystemRandom::new().fill(&mut salt).ok()?;
        let iterations = NonZeroU32::new(ITERATIONS)?;
        let mut digest = [0_u8; DIGEST_LEN];
        pbkdf2::derive(
            pbkdf2::PBKDF2_HMAC_SHA256,
            iterations,
            &salt,
            password.as_bytes(),
            &mut digest,
        );
        Some(Self {
            iterations,
            salt,
            digest,
        })
    }

    /// The stored form, as [`parse`](Self::parse) reads it.
    #[must_use]
    pub fn to_stored(&self) -> String {
        let hex = |bytes: &[u8]| {
            bytes.iter().fold(String::new(), |mut text, byte| {
                let _ = write!(text, "{byte:02x}");
                text
            })
        };
        format!(
            "{SCHEME}:{}:{}:{}",
            self.iterations,
            hex(&self.salt),
            hex(&self.digest)
        )
    }

    /// Whether `password` is the one digested, compared in constant time.
    #[must_use]
    pub fn verify(&self, password: &str) -> bool {
        pbkdf2::verify(
            pbkdf2::PBKDF2_HMAC_SHA256,
            self.iterations,
            &self.salt,
            password.as_bytes(),
            &self.digest,
        )
        .is_ok()
    }
}

/// `text`'s bytes, two hex digits each.
fn from_hex(text: &str) -> Option<Vec<u8>> {
    if !text.len().is_multiple_of(2) {
        return None;
    }
    (0..text.len())
        .step_by(2)
        .map(|at| u8::from_str_radix(text.get(at..at + 2)?, 16).ok())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_digest_made_here_is_read_back_and_checks_its_password_alone() {
        let made = PasswordHash::of("plant-floor").expect("a random source");
        let stored = made.to_stored();
        assert!(stored.starts_with("pbkdf2-sha256:600000:"), "{stored}");
        let read = PasswordHash::parse(&stored).expect("readable");
        assert!(read.verify("plant-floor") && !read.verify("plant-floor "));
        let again = PasswordHash::of("plant-floor").expect("a random source");
        assert_ne!(again.to_stored(), stored, "a fresh salt each time");
    }

    /// `hashlib.pbkdf2_hmac("sha256", b"plant-floor", bytes.fromhex("00112233445566778899aabbccddeeff"), 1000).hex()`
    /// in Python: an implementation other than ring's.
    const STORED: &str = "pbkdf2-sha256:1000:00112233445566778899aabbccddeeff:\
        fad0bcb096faa2e53bb829d9ee6d2bae630b17dfc9b9bc3728735ecec40b91e7";

    #[test]
    fn a_digest_made_elsewhere_verifies_its_password_only() {
        let hash = PasswordHash::parse(STORED).unwrap();
        assert!(hash.verify("plant-floor"));
        assert!(!hash.verify("plant-floor "));
        assert!(!hash.verify(""));
    }

    #[test]
    fn malformed_digests_are_refused_without_echoing_them() {
        for text in [
            "",
            "sha256:1000:00112233445566778899aabbccddeeff:00",
            "pbkdf2-sha256:10:00112233445566778899aabbccddeeff:00",
            "pbkdf2-sha256:1000:0011:00",
            STORED.trim_end_matches('7'),
            &format!("{STORED}:extra"),
        ] {
            let error = PasswordHash::parse(text).unwrap_err();
            assert!(!error.to_string().contains("00112233"), "{error}");
        }
    }
}
