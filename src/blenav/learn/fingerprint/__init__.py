"""LocNet and TransNet+LocNet on fingerprint windows of real walks (WiFi / BLE / both): :mod:`.train`, run through
the cross-phone localizer's training pipeline. Nothing is imported here."""
