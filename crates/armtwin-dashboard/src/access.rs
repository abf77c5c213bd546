//! The dashboard's door: every request but `/healthz` shows a token whose role reads its path
//! (the decision is [`armtwin_access::http_access::decide`]); a browser without one is asked for it.

use std::sync::Arc;

use axum::extract::{Request, State};
use axum::http::{HeaderValue, StatusCode, header};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};

use armtwin_access::http_access::{Decision, Token, decide};

/// The middleware.
pub(super) async fn guard(
    State(tokens): State<Arc<[Token]>>,
    request: Request,
    next: Next,
) -> Response {
    let authorization = request
        .headers()
        .get(header::AUTHORIZATION)
        .and_then(|value| value.to_str().ok());
    match decide(&tokens, request.uri().path(), authorization) {
        Decision::Allow => next.run(request).await,
        Decision::Unauthenticated => (
            StatusCode::UNAUTHORIZED,
            [(
                header::WWW_AUTHENTICATE,
                HeaderValue::from_static("Basic realm=\"armtwin\", charset=\"UTF-8\""),
            )],
            "a token is needed: Authorization: Bearer <token>, or Basic with the token's name\n",
        )
            .into_response(),
        Decision::Forbidden => (
            StatusCode::FORBIDDEN,
            "this token's role does not read this page\n",
        )
            .into_response(),
    }
}
