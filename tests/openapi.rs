//! The committed `openapi/openapi.json` is the spec the code generates.
//! Regenerate with `UPDATE_OPENAPI=1 cargo test --test openapi`.

#[test]
fn committed_openapi_matches_the_code() {
    let generated = ilqr_service::server::openapi_json() + "\n";
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/openapi/openapi.json");
    if std::env::var_os("UPDATE_OPENAPI").is_some() {
        std::fs::write(path, &generated).unwrap();
    }
    let committed = std::fs::read_to_string(path).unwrap_or_default();
    assert!(
        committed == generated,
        "openapi/openapi.json is stale: run `UPDATE_OPENAPI=1 cargo test --release --test openapi`"
    );
}

#[test]
fn the_spec_documents_every_status_and_bounds_the_arrays() {
    let spec: serde_json::Value =
        serde_json::from_str(&ilqr_service::server::openapi_json()).unwrap();
    let responses = &spec["paths"]["/solve"]["post"]["responses"];
    for status in ["200", "400", "413", "415", "422", "500", "503"] {
        assert!(
            responses[status].is_object(),
            "/solve does not document {status}"
        );
    }
    let problem = &spec["components"]["schemas"]["ProblemSpec"];
    assert_eq!(problem["properties"]["initial_state"]["minItems"], 6);
    assert_eq!(problem["properties"]["initial_state"]["maxItems"], 6);
    assert_eq!(problem["additionalProperties"], false);
    assert!(problem.get("required").is_none(), "every field is optional");
    let gains = &spec["components"]["schemas"]["Gains"]["properties"]["feedback"];
    assert_eq!(gains["items"]["minItems"], 2);
    assert_eq!(gains["items"]["items"]["maxItems"], 6);
}
