"""The drive gateway's Modbus/TCP contract, client side and codec (docs/gateway.md).

Owns the register map, the frame codec, the loopback-only network policy, the client and the
setpoint stream. Knows nothing of robots: joint vectors in, joint vectors out.

May import: `rxcomm.errors` only.
"""
