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
    for status in [
        "200", "400", "405", "408", "413", "414", "415", "422", "431", "500", "503",
    ] {
        assert!(
            responses[status].is_object(),
            "/solve does not document {status}"
        );
    }
    // The middleware sets x-request-id on every answer it sees, so every
    // answer declares it but 414 and 431, which the HTTP layer gives first.
    let paths = spec["paths"].as_object().unwrap();
    for (path, item) in paths {
        for (method, operation) in item.as_object().unwrap() {
            for (status, response) in operation["responses"].as_object().unwrap() {
                assert_eq!(
                    response["headers"]["x-request-id"].is_object(),
                    !matches!(status.as_str(), "414" | "431"),
                    "{method} {path} {status} does not declare x-request-id"
                );
            }
        }
    }
    // Every route answers 404 (a wrong path or prefix) and 405 (a wrong
    // method) with a problem document; a generated client drops the body
    // of a status its operation does not declare.
    for (path, item) in paths {
        for (method, operation) in item.as_object().unwrap() {
            for status in ["404", "405"] {
                assert_eq!(
                    operation["responses"][status]["content"]["application/problem+json"]["schema"]
                        ["$ref"],
                    "#/components/schemas/Problem",
                    "{method} {path} {status}"
                );
            }
            assert!(
                operation["responses"]["405"]["headers"]["Allow"].is_object(),
                "{method} {path}: 405 without Allow"
            );
        }
    }
    // No default object beside a $ref (openapi-generator's Go does not
    // compile with them); the referenced schemas carry per-field defaults.
    for (name, schema) in spec["components"]["schemas"].as_object().unwrap() {
        for (field, property) in schema["properties"].as_object().into_iter().flatten() {
            assert!(
                property.get("$ref").is_none()
                    || !property.get("default").is_some_and(|d| d.is_object()),
                "{name}.{field}: {property}"
            );
        }
    }
    let retry_after =
        &spec["paths"]["/solve"]["post"]["responses"]["503"]["headers"]["Retry-After"];
    assert_eq!(retry_after["schema"]["minimum"], 1);
    // The budget's maximum is the service's default one.
    assert_eq!(
        spec["components"]["schemas"]["SolverSpec"]["properties"]["time_limit_ms"]["maximum"],
        ilqr_service::server::Config::default().max_time_limit_ms
    );
    let problem = &spec["components"]["schemas"]["ProblemSpec"];
    assert_eq!(problem["additionalProperties"], false);
    assert!(problem.get("required").is_none(), "every field is optional");
    // A vector's length is its model's: the description names each
    // model's components, from the registry.
    for m in &ilqr_service::models::MODELS {
        let described = problem["properties"]["initial_state"]["description"]
            .as_str()
            .unwrap_or("");
        let names: Vec<&str> = m.state().iter().map(|q| q.name).collect();
        assert!(
            described.contains(&format!("{}: [{}]", m.name(), names.join(", "))),
            "{described}"
        );
    }
    let gains = &spec["components"]["schemas"]["Gains"]["properties"]["feedback"];
    assert_eq!(gains["items"]["items"]["items"]["type"], "number");
}

/// `model` is one object schema per registered model, with exactly that
/// model's parameters; only the default model's `type` may be left out.
#[test]
fn the_model_schema_is_one_object_per_model() {
    let spec: serde_json::Value =
        serde_json::from_str(&ilqr_service::server::openapi_json()).unwrap();
    let variants = spec["components"]["schemas"]["ProblemSpec"]["properties"]["model"]["oneOf"]
        .as_array()
        .unwrap();
    let models = &ilqr_service::models::MODELS;
    // One per model, then null.
    assert_eq!(variants.len(), models.len() + 1);
    assert_eq!(variants[models.len()]["type"], "null");
    for (m, v) in models.iter().zip(variants) {
        assert_eq!(
            v["properties"]["type"]["enum"],
            serde_json::json!([m.name()])
        );
        assert_eq!(v["additionalProperties"], false);
        let required = v["required"].as_array().map(Vec::len).unwrap_or(0);
        assert_eq!(
            required == 0,
            m.name() == ilqr_service::models::DEFAULT_MODEL,
            "{}",
            m.name()
        );
        let properties = v["properties"].as_object().unwrap();
        assert_eq!(properties.len(), 1 + m.parameters().len(), "{}", m.name());
        for p in m.parameters() {
            let f = &properties[p.name];
            assert_eq!(f["minimum"].as_f64(), Some(p.minimum), "{}", p.name);
            assert_eq!(f["maximum"].as_f64(), Some(p.maximum), "{}", p.name);
            assert_eq!(f["default"].as_f64(), Some(p.default), "{}", p.name);
        }
    }
}

/// The ranges in the schema are the ones validation enforces (utoipa's
/// attributes need literals, so they are written twice).
#[test]
fn the_spec_states_the_validated_ranges() {
    use ilqr_service::problem::{MAX_CONTROL, MAX_DT, MAX_STATE, MAX_WEIGHT};
    let spec: serde_json::Value =
        serde_json::from_str(&ilqr_service::server::openapi_json()).unwrap();
    let schemas = &spec["components"]["schemas"];
    let num = |v: &serde_json::Value| v.as_f64().unwrap_or(f64::NAN);
    let problem = &schemas["ProblemSpec"]["properties"];
    assert_eq!(num(&problem["dt"]["maximum"]), MAX_DT);
    for field in ["initial_state", "goal_state"] {
        assert_eq!(
            num(&problem[field]["items"]["maximum"]),
            MAX_STATE,
            "{field}"
        );
        assert_eq!(
            num(&problem[field]["items"]["minimum"]),
            -MAX_STATE,
            "{field}"
        );
    }
    assert_eq!(
        num(&problem["initial_controls"]["items"]["items"]["maximum"]),
        MAX_CONTROL
    );
    for field in ["state", "control", "terminal"] {
        let w = &schemas["Weights"]["properties"][field]["items"];
        assert_eq!(num(&w["maximum"]), MAX_WEIGHT, "{field}");
    }
    let obstacle = &schemas["Obstacle"]["properties"];
    assert_eq!(num(&obstacle["weight"]["maximum"]), MAX_WEIGHT);
    assert_eq!(num(&obstacle["center"]["items"]["maximum"]), MAX_STATE);
}

/// An obstacle's weight defaults to the seed obstacle's, and the spec says
/// so; its centre is the one required member of any problem object.
#[test]
fn an_obstacle_requires_its_center_only_and_states_the_weights_default() {
    let spec: serde_json::Value =
        serde_json::from_str(&ilqr_service::server::openapi_json()).unwrap();
    let obstacle = &spec["components"]["schemas"]["Obstacle"];
    assert_eq!(obstacle["required"], serde_json::json!(["center"]));
    let seed = serde_json::to_value(ilqr_service::problem::ProblemSpec::default()).unwrap();
    assert_eq!(
        obstacle["properties"]["weight"]["default"],
        seed["obstacles"][0]["weight"]
    );
}

/// Every `default` the spec states is the value an omitted field takes,
/// and a member whose default depends on the model names each model's in
/// its description, as the registry has it.
#[test]
fn the_spec_states_the_defaults_the_code_applies() {
    let spec: serde_json::Value =
        serde_json::from_str(&ilqr_service::server::openapi_json()).unwrap();
    let schemas = &spec["components"]["schemas"];
    let defaults = serde_json::to_value(ilqr_service::problem::ProblemSpec::default()).unwrap();
    let mut checked = 0;
    for (schema, value) in [
        ("SolverSpec", &defaults["solver"]),
        ("OutputSpec", &defaults["output"]),
    ] {
        let properties = schemas[schema]["properties"].as_object().unwrap();
        for (name, property) in properties {
            // The time budget's default is the service's configured one,
            // stated in words only: as a schema default, generated clients
            // would send it and override it.
            // `multi_start`'s depends on whether controls are given, so it
            // too is stated in words.
            if name == "time_limit_ms" || name == "multi_start" {
                assert!(property.get("default").is_none(), "{property}");
                continue;
            }
            assert_eq!(
                property.get("default"),
                Some(&value[name]),
                "{schema}.{name}: the spec's default is not the code's"
            );
            checked += 1;
        }
    }
    assert_eq!(checked, 7);
    let problem = &schemas["ProblemSpec"]["properties"];
    assert_eq!(problem["integrator"]["default"], defaults["integrator"]);
    // Model-dependent members state no single default, and list each
    // model's in words.
    for m in &ilqr_service::models::MODELS {
        let d = ilqr_service::problem::ProblemSpec::default_for(*m);
        let list = |xs: &[f64]| {
            let xs: Vec<String> = xs.iter().map(|x| x.to_string()).collect();
            format!("[{}]", xs.join(", "))
        };
        for (member, schema, value) in [
            ("dt", &problem["dt"], d.dt.to_string()),
            ("horizon", &problem["horizon"], d.horizon.to_string()),
            (
                "initial_state",
                &problem["initial_state"],
                list(&d.initial_state),
            ),
            ("goal_state", &problem["goal_state"], list(&d.goal_state)),
            (
                "state",
                &schemas["Weights"]["properties"]["state"],
                list(&d.weights.state),
            ),
            (
                "control",
                &schemas["Weights"]["properties"]["control"],
                list(&d.weights.control),
            ),
            (
                "terminal",
                &schemas["Weights"]["properties"]["terminal"],
                list(&d.weights.terminal),
            ),
        ] {
            assert!(schema.get("default").is_none(), "{member}");
            let described = schema["description"].as_str().unwrap_or("");
            let at = described
                .find(&format!("{}: ", m.name()))
                .unwrap_or_else(|| panic!("{member}: no `{}` in {described}", m.name()));
            let own = described[at..].split(';').next().unwrap_or("");
            assert!(
                own.contains(&value),
                "{member} of {}: {value} not in {own}",
                m.name()
            );
        }
    }
}

/// The answers never hold `null` (left-out members are absent, and every
/// number is finite), so no schema reachable from `SolveResult` or the
/// problem+json `Problem` may admit it: a client generated from the spec
/// would otherwise type `gains`, `trace` or `retry_after` as nullable and
/// make every caller check for a value that never comes.
#[test]
fn nothing_in_the_answer_schemas_admits_null() {
    let spec: serde_json::Value =
        serde_json::from_str(&ilqr_service::server::openapi_json()).unwrap();
    let schemas = &spec["components"]["schemas"];
    fn nulls(
        v: &serde_json::Value,
        schemas: &serde_json::Value,
        at: String,
        seen: &mut Vec<String>,
        out: &mut Vec<String>,
    ) {
        match v {
            serde_json::Value::Object(map) => {
                if let Some(r) = map.get("$ref").and_then(|r| r.as_str()) {
                    let name = r.trim_start_matches("#/components/schemas/").to_string();
                    if !seen.contains(&name) {
                        seen.push(name.clone());
                        nulls(
                            &schemas[&name],
                            schemas,
                            format!("{at} -> {name}"),
                            seen,
                            out,
                        );
                    }
                }
                let t = map.get("type");
                let admits = t == Some(&serde_json::json!("null"))
                    || t.and_then(|t| t.as_array())
                        .is_some_and(|a| a.contains(&serde_json::json!("null")))
                    || map.get("nullable") == Some(&serde_json::json!(true));
                if admits {
                    out.push(at.clone());
                }
                for (k, child) in map {
                    nulls(child, schemas, format!("{at}/{k}"), seen, out);
                }
            }
            serde_json::Value::Array(items) => {
                for (i, child) in items.iter().enumerate() {
                    nulls(child, schemas, format!("{at}/{i}"), seen, out);
                }
            }
            _ => {}
        }
    }
    let (mut seen, mut out) = (
        vec!["SolveResult".to_string(), "Problem".to_string()],
        Vec::new(),
    );
    for root in ["SolveResult", "Problem"] {
        nulls(&schemas[root], schemas, root.into(), &mut seen, &mut out);
    }
    assert!(
        ["Gains", "TraceEntry", "FieldError"]
            .iter()
            .all(|s| seen.contains(&s.to_string())),
        "{seen:?}"
    );
    assert!(
        out.is_empty(),
        "schemas admitting null in the result: {out:?}"
    );
}
