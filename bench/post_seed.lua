-- wrk script: POST the seed problem to /solve and count the HTTP statuses.
--
--   wrk -t2 -c8 -d15s --latency -s bench/post_seed.lua http://127.0.0.1:PORT/solve
--   wrk ... -s bench/post_seed.lua http://127.0.0.1:PORT/solve -- full
--   wrk ... -s bench/post_seed.lua http://127.0.0.1:PORT/solve -- lean count
--
-- Bodies (the seed's single solve, as these figures have always measured):
--   "lean" (default) = {"solver":{"multi_start":false},"output":{"gains":false,"trace":false}},
--   "full"           = {"solver":{"multi_start":false},"output":{"gains":true,"trace":true}}.
--
-- Counting. With "count", every thread counts the answers by status in its
-- own Lua state's `statuses` table; `done` (in the main state) collects them
-- through the thread objects kept by `setup`. That needs a `response`
-- callback, and with one defined wrk parses every header and copies every
-- body into Lua: 10-20 us of CPU per answer, taken from the same two
-- cores the server runs on. So saturation runs leave "count" off and rely
-- on wrk's own tally, which is exact for this server: wrk counts every
-- status >= 400 in errors.status, and /solve answers 200 or >= 400.
--
-- Besides wrk's report it prints lines for bench/load.sh to parse:
--   STATUS 200=1234 503=56          with "count": answers by status
--   STATUS 200=1234 error=56        without: 200 = requests - errors.status
--   ERRORS connect=0 read=0 write=0 timeout=0 status=56
--   RESULT requests=1290 duration_s=15.00 ok_per_s=82.27 p50_us=... p90_us=... p99_us=... max_us=...
-- (ok_per_s counts only 200 answers; latencies are over all answers.)

local bodies = {
  lean = '{"solver":{"multi_start":false},"output":{"gains":false,"trace":false}}',
  full = '{"solver":{"multi_start":false},"output":{"gains":true,"trace":true}}',
}

local threads = {}
local counting = false

function setup(thread)
  table.insert(threads, thread)
end

function init(args)
  local variant = args[1] or "lean"
  local body = bodies[variant]
  if body == nil then
    error("unknown body variant '" .. variant .. "' (use lean or full)")
  end
  if args[2] ~= nil and args[2] ~= "count" then
    error("unknown option '" .. args[2] .. "' (use count or nothing)")
  end
  wrk.method = "POST"
  wrk.body = body
  wrk.headers["Content-Type"] = "application/json"
  statuses = {}
  if args[2] == "count" then
    -- wrk looks for a global `response` after `init` has run.
    response = function(status, headers, body)
      statuses[status] = (statuses[status] or 0) + 1
    end
  end
end

function done(summary, latency, requests)
  local e = summary.errors
  local total = {}
  for _, thread in ipairs(threads) do
    local counts = thread:get("statuses") or {}
    for code, n in pairs(counts) do
      total[code] = (total[code] or 0) + n
      counting = true
    end
  end
  local parts = {}
  if counting then
    local codes = {}
    for code in pairs(total) do
      table.insert(codes, code)
    end
    table.sort(codes)
    for _, code in ipairs(codes) do
      table.insert(parts, string.format("%d=%d", code, total[code]))
    end
  else
    total[200] = summary.requests - e.status
    parts = { string.format("200=%d", total[200]), string.format("error=%d", e.status) }
  end
  io.write("STATUS " .. table.concat(parts, " ") .. "\n")

  io.write(string.format("ERRORS connect=%d read=%d write=%d timeout=%d status=%d\n",
    e.connect, e.read, e.write, e.timeout, e.status))

  local seconds = summary.duration / 1e6
  io.write(string.format(
    "RESULT requests=%d duration_s=%.3f ok_per_s=%.2f p50_us=%d p90_us=%d p99_us=%d max_us=%d\n",
    summary.requests, seconds, (total[200] or 0) / seconds,
    latency:percentile(50), latency:percentile(90), latency:percentile(99), latency.max))
end
