//! A fleet's certificates by role (`armtwin certs`): its CA; the router's certificate, the one
//! that may serve (`serverAuth`, and client too, for routers that connect to each other), naming
//! the hosts clients reach it by; and one certificate per name of the fleet description, a client
//! only (`clientAuth`), its name as the subject's common name, which the router's access control
//! matches (`cert_common_names`). So no identity's certificate can pose as the router.
//!
//! P-256 ECDSA keys (rcgen on ring, the provider the rest of the tree uses). Returns PEM text;
//! must not write files: the command line does, keys readable by their owner only.

pub mod names;

use std::time::{Duration, SystemTime};

use rcgen::{
    BasicConstraints, CertificateParams, DistinguishedName, DnType, ExtendedKeyUsagePurpose, IsCa,
    Issuer, KeyPair, KeyUsagePurpose, SanType,
};
use thiserror::Error;

use self::names::{RouterName, file_stem};
use crate::acl::Fleet;

pub use self::names::NameError;

/// The router certificate's common name and files' stem.
pub const ROUTER: &str = "router";
/// The CA's files' stem.
pub const CA: &str = "ca";
/// How long the CA is valid: it outlives many rounds of the certificates it signs.
const CA_DAYS: u64 = 3650;
/// How far before now a certificate starts to be valid: a host whose clock is a little behind
/// the one that made it still takes it.
const CLOCK_SKEW: Duration = Duration::from_secs(300);
/// The longest validity `--days` may ask for (the CA's own).
pub const MAX_DAYS: u32 = 3650;

/// Why the certificates cannot be made.
#[derive(Debug, Error)]
pub enum CertsError {
    /// A name cannot be written.
    #[error(transparent)]
    Name(#[from] NameError),
    /// `--days` out of range.
    #[error("--days {days}: a certificate is valid for 1 to {MAX_DAYS} days")]
    Days {
        /// The days given.
        days: u32,
    },
    /// The router has no name to be reached by.
    #[error("the router needs at least one name (--router-name)")]
    NoRouterName,
    /// rcgen refused (a key that could not be made, a name it cannot encode).
    #[error("cannot make {which}'s certificate: {reason}")]
    Generation {
        /// The certificate's stem.
        which: String,
        /// rcgen's reason.
        reason: String,
    },
}

/// One certificate and its private key, as PEM.
#[derive(Debug, Clone)]
pub struct Issued {
    /// The files' stem: `ca`, `router` or a fleet name.
    pub stem: String,
    /// The certificate (PEM).
    pub certificate_pem: String,
    /// Its PKCS#8 private key (PEM).
    pub private_key_pem: String,
}

/// The CA first, then the router, then every fleet name in the description's order of names.
pub fn issue(
    fleet: &Fleet,
    router_names: &[RouterName],
    days: u32,
) -> Result<Vec<Issued>, CertsError> {
    if days == 0 || days > MAX_DAYS {
        return Err(CertsError::Days { days });
    }
    if router_names.is_empty() {
        return Err(CertsError::NoRouterName);
    }
    let stems: Vec<&str> = fleet
        .names()
        .into_iter()
        .map(|(name, _)| file_stem(name))
        .collect::<Result<_, _>>()?;
    let now = SystemTime::now();
    let failed = |which: &str| {
        let which = which.to_owned();
        move |e: rcgen::Error| CertsError::Generation {
            which,
            reason: e.to_string(),
        }
    };

    let ca_key = KeyPair::generate().map_err(failed(CA))?;
    let mut ca_params = params("fleet-ca", now, CA_DAYS);
    ca_params.is_ca = IsCa::Ca(BasicConstraints::Unconstrained);
    ca_params.key_usages = vec![KeyUsagePurpose::KeyCertSign, KeyUsagePurpose::CrlSign];
    let ca_certificate = ca_params.self_signed(&ca_key).map_err(failed(CA))?;
    let mut issued = vec![Issued {
        stem: CA.to_owned(),
        certificate_pem: ca_certificate.pem(),
        private_key_pem: ca_key.serialize_pem(),
    }];
    let issuer = Issuer::new(ca_params, ca_key);

    let mut router = params(ROUTER, now, u64::from(days));
    router.subject_alt_names = router_names
        .iter()
        .map(|name| match name {
            RouterName::Ip(ip) => Ok(SanType::IpAddress(*ip)),
            RouterName::Dns(dns) => dns.clone().try_into().map(SanType::DnsName),
        })
        .collect::<Result<_, _>>()
        .map_err(failed(ROUTER))?;
    router.extended_key_usages = vec![
        ExtendedKeyUsagePurpose::ServerAuth,
        ExtendedKeyUsagePurpose::ClientAuth,
    ];
    issued.push(leaf(ROUTER, router, &issuer).map_err(failed(ROUTER))?);

    for stem in stems {
        let mut client = params(stem, now, u64::from(days));
        client.extended_key_usages = vec![ExtendedKeyUsagePurpose::ClientAuth];
        issued.push(leaf(stem, client, &issuer).map_err(failed(stem))?);
    }
    Ok(issued)
}

/// A certificate's parameters: its subject's common name, valid from a little before `now` for
/// `days`.
fn params(common_name: &str, now: SystemTime, days: u64) -> CertificateParams {
    let mut params = CertificateParams::default();
    params.distinguished_name = DistinguishedName::new();
    params
        .distinguished_name
        .push(DnType::CommonName, common_name);
    params.not_before = (now - CLOCK_SKEW).into();
    params.not_after = (now + Duration::from_secs(days * 86_400)).into();
    params
}

/// An end entity's certificate and new key, signed by the CA: a signing key, never a CA.
fn leaf(
    stem: &str,
    mut params: CertificateParams,
    issuer: &Issuer<'_, KeyPair>,
) -> Result<Issued, rcgen::Error> {
    params.is_ca = IsCa::ExplicitNoCa;
    params.key_usages = vec![KeyUsagePurpose::DigitalSignature];
    params.use_authority_key_identifier_extension = true;
    let key = KeyPair::generate()?;
    let certificate = params.signed_by(&key, issuer)?;
    Ok(Issued {
        stem: stem.to_owned(),
        certificate_pem: certificate.pem(),
        private_key_pem: key.serialize_pem(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fleet() -> Fleet {
        Fleet::parse("armtwin = [\"armtwin\"]\n[gateways]\ng1 = [\"r1\"]\n").expect("a fleet")
    }

    #[test]
    fn the_ca_the_router_and_every_name_are_issued() {
        let issued = issue(&fleet(), &["localhost".parse().expect("a name")], 1).expect("issued");
        let stems: Vec<&str> = issued.iter().map(|i| i.stem.as_str()).collect();
        assert_eq!(stems, ["ca", "router", "armtwin", "g1"]);
        for one in &issued {
            assert!(
                one.certificate_pem
                    .starts_with("-----BEGIN CERTIFICATE-----")
            );
            assert!(
                one.private_key_pem
                    .starts_with("-----BEGIN PRIVATE KEY-----")
            );
        }
    }

    #[test]
    fn bad_requests_are_refused_with_the_reason() {
        let router = ["localhost".parse().expect("a name")];
        for (days, names, expected) in [
            (0, &router[..], "--days 0"),
            (MAX_DAYS + 1, &router[..], "1 to 3650 days"),
            (1, &[][..], "--router-name"),
        ] {
            let error = issue(&fleet(), names, days)
                .expect_err(expected)
                .to_string();
            assert!(error.contains(expected), "{error}");
        }
        let taken = Fleet::parse("armtwin = [\"router\"]\n").expect("a fleet");
        let error = issue(&taken, &router, 1).expect_err("reserved").to_string();
        assert!(error.contains("'router'"), "{error}");
    }
}
