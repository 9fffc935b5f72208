-- wrk script: POST a problem that fails validation ({"dt": -1}, a 422), to
-- measure what the HTTP stack, parsing, validation and the problem+json
-- answer cost per request without a solve:
--
--   wrk -t1 -c4 -d5s -s bench/post_invalid.lua http://127.0.0.1:PORT/solve
wrk.method = "POST"
wrk.body = '{"dt": -1}'
wrk.headers["Content-Type"] = "application/json"
