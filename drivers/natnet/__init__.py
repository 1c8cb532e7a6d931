"""OptiTrack Motive's NatNet stream: wire format, messages, UDP transport, tracker driver and a fake Motive."""
