"""The spcodec reference encoder (extra ``encoder``): categorization, sketch and patch encoding."""
