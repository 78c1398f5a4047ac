"""Correctors: pull an estimate towards what aiding sensors say."""
