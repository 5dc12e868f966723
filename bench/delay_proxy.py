#!/usr/bin/env python3
# A TCP proxy on 127.0.0.1 for the benchmarks (bench/lib.sh's start_delayed_s3):
# every chunk a client sends (an HTTP request: its headers
# arrive in one read) waits DELAY_MS before it is forwarded.
# Usage: delay_proxy.py LISTEN_PORT TARGET_PORT DELAY_MS
import asyncio, sys
listen, target, delay = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3]) / 1000
async def pipe(r, w, wait):
    try:
        while True:
            data = await r.read(65536)
            if not data:
                break
            if wait:
                await asyncio.sleep(delay)
            w.write(data)
            await w.drain()
    except (ConnectionError, asyncio.CancelledError):
        pass
    finally:
        w.close()
async def handle(cr, cw):
    sr, sw = await asyncio.open_connection("127.0.0.1", target)
    await asyncio.gather(pipe(cr, sw, True), pipe(sr, cw, False))
async def main():
    srv = await asyncio.start_server(handle, "127.0.0.1", listen)
    async with srv:
        await srv.serve_forever()
asyncio.run(main())
