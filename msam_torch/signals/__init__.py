"""Sampled signals: derivatives and states estimated from them (:mod:`.derivatives`), the band they
occupy (:mod:`.bandwidth`) and an input's shape between samples (:mod:`.hold`)."""
