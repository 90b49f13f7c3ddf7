"""The plant process: the true system, its noise, and every agent's measurements."""
