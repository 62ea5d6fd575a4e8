"""Live lip sync from a microphone (issue 33): ``dualtalker-lite live --checkpoint M.pt``.

:mod:`.stream` holds the streaming front end and the incremental decoder (no network), :mod:`.server` the aiohttp
server and its safety rules, ``page/`` the browser page (three.js vendored in ``export/vendor/three``). See
``docs/live.md``.
"""
