//! Who may sign in, and what they may do: read, and for operators acknowledge and confirm
//! alarm conditions. User names and passwords (checked against their PBKDF2 digests) on the
//! encrypted endpoints, anonymous clients (readers) only when configured, and no write access
//! for anyone: a twin changes through the admin keys behind the ACL, never through OPC UA.
//!
//! Must not log a password.

use std::collections::BTreeMap;

use async_trait::async_trait;
use opcua::server::address_space::AccessLevel;
use opcua::server::authenticator::{
    AuthManager, Password, UserToken, user_pass_security_policy_id,
};
use opcua::server::{ANONYMOUS_USER_TOKEN_ID, ServerEndpoint};
use opcua::types::{Error, MethodId, NodeId, StatusCode, UAString, UserTokenPolicy, UserTokenType};
use tracing::warn;

use crate::password::PasswordHash;
use crate::settings::{Role, User};

/// The user token id the encrypted endpoints list for the configured users.
pub(crate) const USERS_TOKEN_ID: &str = "users";

/// The policy id of the anonymous token (async-opcua's own).
const POLICY_ID_ANONYMOUS: &str = "anonymous";

/// The server's [`AuthManager`].
pub(crate) struct Access {
    users: BTreeMap<String, (PasswordHash, Role)>,
    anonymous: bool,
}

impl Access {
    pub(crate) fn new(users: &[User], anonymous: bool) -> Self {
        Self {
            users: users
                .iter()
                .map(|user| (user.name.clone(), (user.password.clone(), user.role)))
                .collect(),
            anonymous,
        }
    }
}

fn rejected(message: &str) -> Error {
    Error::new(StatusCode::BadIdentityTokenRejected, message.to_owned())
}

#[async_trait]
impl AuthManager for Access {
    async fn authenticate_anonymous_token(&self, endpoint: &ServerEndpoint) -> Result<(), Error> {
        if self.anonymous && endpoint.user_token_ids.contains(ANONYMOUS_USER_TOKEN_ID) {
            Ok(())
        } else {
            warn!(endpoint = %endpoint.path, "OPC UA: anonymous sign-in refused");
            Err(rejected("anonymous access is off"))
        }
    }

    async fn authenticate_username_identity_token(
        &self,
        endpoint: &ServerEndpoint,
        username: &str,
        password: &Password,
    ) -> Result<UserToken, Error> {
        let known = endpoint.user_token_ids.contains(USERS_TOKEN_ID)
            && self
                .users
                .get(username)
                .is_some_and(|(hash, _)| hash.verify(password.get()));
        if known {
            Ok(UserToken(username.to_owned()))
        } else {
            // One answer for an unknown name and a wrong password: names are not disclosed.
            warn!(user = username, "OPC UA: sign-in refused");
            Err(rejected("unknown user name or wrong password"))
        }
    }

    fn effective_user_access_level(
        &self,
        _token: &UserToken,
        user_access_level: AccessLevel,
        _node_id: &NodeId,
    ) -> AccessLevel {
        // Read-only for everyone, whatever a node's own access level says.
        user_access_level & (AccessLevel::CURRENT_READ | AccessLevel::HISTORY_READ)
    }

    fn is_user_executable(&self, token: &UserToken, method_id: &NodeId) -> bool {
        match method_id.as_method_id() {
            Ok(
                MethodId::ConditionType_ConditionRefresh
                | MethodId::ConditionType_ConditionRefresh2,
            ) => true,
            Ok(
                MethodId::AcknowledgeableConditionType_Acknowledge
                | MethodId::AcknowledgeableConditionType_Confirm,
            ) => {
                // Anonymous clients have no entry: readers.
                self.users
                    .get(&token.0)
                    .is_some_and(|(_, role)| *role == Role::Operator)
            }
            _ => false,
        }
    }

    fn user_token_policies(&self, endpoint: &ServerEndpoint) -> Vec<UserTokenPolicy> {
        let mut policies = Vec::with_capacity(2);
        if self.anonymous && endpoint.user_token_ids.contains(ANONYMOUS_USER_TOKEN_ID) {
            policies.push(UserTokenPolicy {
                policy_id: UAString::from(POLICY_ID_ANONYMOUS),
                token_type: UserTokenType::Anonymous,
                issued_token_type: UAString::null(),
                issuer_endpoint_url: UAString::null(),
                security_policy_uri: UAString::null(),
            });
        }
        if !self.users.is_empty() && endpoint.user_token_ids.contains(USERS_TOKEN_ID) {
            policies.push(UserTokenPolicy {
                policy_id: user_pass_security_policy_id(endpoint),
                token_type: UserTokenType::UserName,
                issued_token_type: UAString::null(),
                issuer_endpoint_url: UAString::null(),
                security_policy_uri: UAString::null(),
            });
        }
        policies
    }
}
