-- wrk script: POST the seed problem to /solve and count the HTTP statuses.
--
--   wrk -t2 -c8 -d15s --latency -s bench/post_seed.lua http://127.0.0.1:PORT/solve
--   wrk ... -s bench/post_seed.lua http://127.0.0.1:PORT/solve -- full
--
-- Bodies: "lean" (default) = {"output":{"gains":false,"trace":false}},
--         "full"           = {"output":{"gains":true,"trace":true}}.
--
-- wrk runs every thread in its own Lua state, so each thread counts its
-- statuses in its own `statuses` table; `done` (in the main state) collects
-- them through the thread objects kept by `setup`. Besides wrk's report it
-- prints lines for bench/load.sh to parse:
--   STATUS 200=1234 503=56          responses by status
--   ERRORS connect=0 read=0 write=0 timeout=0 status=56
--   RESULT requests=1290 duration_s=15.00 ok_per_s=82.27 p50_us=... p90_us=... p99_us=... max_us=...
-- (ok_per_s counts only 200 answers; latencies are over all answers.)

local bodies = {
  lean = '{"output":{"gains":false,"trace":false}}',
  full = '{"output":{"gains":true,"trace":true}}',
}

local threads = {}

function setup(thread)
  table.insert(threads, thread)
end

function init(args)
  local variant = args[1] or "lean"
  local body = bodies[variant]
  if body == nil then
    error("unknown body variant '" .. variant .. "' (use lean or full)")
  end
  wrk.method = "POST"
  wrk.body = body
  wrk.headers["Content-Type"] = "application/json"
  statuses = {}
end

function response(status, headers, body)
  statuses[status] = (statuses[status] or 0) + 1
end

function done(summary, latency, requests)
  local total = {}
  for _, thread in ipairs(threads) do
    local counts = thread:get("statuses") or {}
    for code, n in pairs(counts) do
      total[code] = (total[code] or 0) + n
    end
  end
  local codes = {}
  for code in pairs(total) do
    table.insert(codes, code)
  end
  table.sort(codes)
  local parts = {}
  for _, code in ipairs(codes) do
    table.insert(parts, string.format("%d=%d", code, total[code]))
  end
  io.write("STATUS " .. table.concat(parts, " ") .. "\n")

  local e = summary.errors
  io.write(string.format("ERRORS connect=%d read=%d write=%d timeout=%d status=%d\n",
    e.connect, e.read, e.write, e.timeout, e.status))

  local seconds = summary.duration / 1e6
  io.write(string.format(
    "RESULT requests=%d duration_s=%.3f ok_per_s=%.2f p50_us=%d p90_us=%d p99_us=%d max_us=%d\n",
    summary.requests, seconds, (total[200] or 0) / seconds,
    latency:percentile(50), latency:percentile(90), latency:percentile(99), latency.max))
end
