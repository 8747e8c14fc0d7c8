"""Device drivers: one package per device, each a sans-IO protocol, a thin asyncio driver and an emulator."""
