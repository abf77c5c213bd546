//! A gateway message's transport into its codec: which decoder a Zenoh sample's encoding selects.
//! Decoding and stepping the twin are the codec crate's ([`armtwin_codec::decoded`],
//! [`armtwin_codec::gateway`], re-exported here for the callers that feed the pipeline: the
//! service, `validate` and the benchmarks).
//!
//! Must not decode anything itself, nor know the filesystem: a Zenoh `Encoding` is a value, so
//! reading one needs no session.

use std::borrow::Cow;
use std::sync::LazyLock;

use zenoh::bytes::Encoding;

pub use armtwin_codec::gateway::{
    Codec, SourceCodec, joint_message, measured_message, untracked_robot,
};
use armtwin_codec::zser;

/// `zenoh/serialized;armtwin/joints/v1`, built once: comparing with it needs no allocation.
static JOINTS_ENCODING: LazyLock<Encoding> =
    LazyLock::new(|| Encoding::ZENOH_SERIALIZED.with_schema(zser::JOINTS_SCHEMA));
/// `zenoh/serialized;armtwin/joints/v2`.
static JOINTS_STATE_ENCODING: LazyLock<Encoding> =
    LazyLock::new(|| Encoding::ZENOH_SERIALIZED.with_schema(zser::JOINTS_STATE_SCHEMA));
/// `zenoh/serialized;armtwin/pose/v1`.
static POSE_ENCODING: LazyLock<Encoding> =
    LazyLock::new(|| Encoding::ZENOH_SERIALIZED.with_schema(zser::POSE_SCHEMA));

/// The codec of a sample's encoding: `zenoh/serialized` (with its schema) is Zenoh's
/// serialization; any other encoding, the default `zenoh/bytes` included, is JSON, so a gateway
/// that sets none keeps working ([`Codec::from_encoding_name`], without its allocation for the
/// usual encodings).
#[must_use]
pub fn codec_of(encoding: &Encoding) -> Codec {
    if *encoding == *JOINTS_ENCODING {
        return Codec::ZenohSerialized(Some(zser::Schema::Joints));
    }
    if *encoding == *JOINTS_STATE_ENCODING {
        return Codec::ZenohSerialized(Some(zser::Schema::JointsState));
    }
    if *encoding == *POSE_ENCODING {
        return Codec::ZenohSerialized(Some(zser::Schema::Pose));
    }
    if *encoding == Encoding::ZENOH_SERIALIZED {
        return Codec::ZenohSerialized(None);
    }
    // Allocates only for an encoding with a schema, which JSON gateways rarely set.
    Codec::from_encoding_name(&Cow::<str>::from(encoding))
}

#[cfg(test)]
mod tests {
    use super::*;
    use armtwin_codec::zser::Schema;

    #[test]
    fn the_encoding_selects_the_codec() {
        let serialized = |schema: &str| Encoding::ZENOH_SERIALIZED.with_schema(schema);
        let cases = [
            (
                serialized("armtwin/joints/v1"),
                Codec::ZenohSerialized(Some(Schema::Joints)),
            ),
            (
                serialized("armtwin/joints/v2"),
                Codec::ZenohSerialized(Some(Schema::JointsState)),
            ),
            (
                serialized("armtwin/pose/v1"),
                Codec::ZenohSerialized(Some(Schema::Pose)),
            ),
            // A schema this build does not know is left to the decoder to refuse.
            (
                serialized("armtwin/joints/v99"),
                Codec::ZenohSerialized(None),
            ),
            (Encoding::ZENOH_SERIALIZED, Codec::ZenohSerialized(None)),
            (
                Encoding::from("zenoh/serialized;armtwin/pose/v1"),
                Codec::ZenohSerialized(Some(Schema::Pose)),
            ),
            (Encoding::default(), Codec::Json),
            (Encoding::APPLICATION_JSON, Codec::Json),
            (Encoding::TEXT_PLAIN.with_schema("utf-8"), Codec::Json),
            (Encoding::from("my/encoding;armtwin/joints/v1"), Codec::Json),
        ];
        for (encoding, codec) in cases {
            assert_eq!(codec_of(&encoding), codec, "{encoding}");
            // The encoding's text alone selects the same codec.
            assert_eq!(
                Codec::from_encoding_name(&Cow::<str>::from(&encoding)),
                codec,
                "{encoding}"
            );
        }
    }
}
