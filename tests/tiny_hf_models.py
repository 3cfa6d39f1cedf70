"""Tiny random Grounding DINO and OWLv2 checkpoints, built offline for tests.

Each builder writes a model, its image processor and a tokenizer with a small local vocabulary into a folder with
`save_pretrained`, exactly the layout of a downloaded hub snapshot, so the detectors load them through their real
`from_pretrained` code path. The weights are random: the boxes mean nothing, but shapes, post-processing and the
mapping to prompt indices are exercised for real.
"""

from __future__ import annotations

from pathlib import Path

import torch

#: Words the tiny tokenizers know; the test prompts are built from these.
WORDS = ["a", "photo", "of", "the", "mug", "handle", "body", "frying", "pan", "lid", "blade", "spout", "knob"]


def build_tiny_grounding_dino(folder: Path, seed: int = 0) -> Path:
    """Write a tiny random Grounding DINO (Swin backbone, BERT text encoder) with a local WordPiece vocabulary."""
    from transformers import (
        BertConfig,
        BertTokenizer,
        GroundingDinoConfig,
        GroundingDinoForObjectDetection,
        GroundingDinoImageProcessorPil,
        SwinConfig,
    )

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    vocab = ["[PAD]", "[UNK]", "[CLS]", "[SEP]", "[MASK]", ".", ",", "?", "!"] + WORDS + ["##s", "##ing", "##er"]
    tokenizer = BertTokenizer(vocab={token: i for i, token in enumerate(vocab)}, do_lower_case=True, model_max_length=256)

    backbone = SwinConfig(
        image_size=64,
        patch_size=4,
        embed_dim=8,
        depths=[1, 1, 1, 1],
        num_heads=[1, 1, 1, 1],
        window_size=4,
        out_features=["stage2", "stage3", "stage4"],
    )
    text = BertConfig(
        vocab_size=len(vocab),
        hidden_size=16,
        num_hidden_layers=1,
        num_attention_heads=2,
        intermediate_size=32,
        max_position_embeddings=256,
    )
    config = GroundingDinoConfig(
        backbone_config=backbone,
        text_config=text,
        num_queries=20,
        encoder_layers=1,
        decoder_layers=2,  # one decoder layer breaks the tied box-head definition
        encoder_ffn_dim=32,
        decoder_ffn_dim=32,
        encoder_attention_heads=2,
        decoder_attention_heads=2,
        d_model=32,
        num_feature_levels=3,
        encoder_n_points=2,
        decoder_n_points=2,
        max_text_len=256,
    )
    torch.manual_seed(seed)
    model = GroundingDinoForObjectDetection(config).eval()
    processor = GroundingDinoImageProcessorPil(size={"shortest_edge": 64, "longest_edge": 96})
    model.save_pretrained(folder)
    processor.save_pretrained(folder)
    tokenizer.save_pretrained(folder)
    return folder


def build_tiny_owlv2(folder: Path, seed: int = 0) -> Path:
    """Write a tiny random OWLv2 (ViT + CLIP text encoder) with a local byte-level BPE vocabulary and merges."""
    from transformers import (
        CLIPTokenizer,
        Owlv2Config,
        Owlv2ForObjectDetection,
        Owlv2ImageProcessorPil,
    )

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    # As in CLIP's real vocabulary, "!" is id 0 (used as padding) and the start/end tokens come last: OWLv2 treats a
    # query whose first token id is 0 as padding, and CLIP pools the text at the end token.
    letters = [chr(c) for c in range(ord("a"), ord("z") + 1)]
    # CLIP's BPE marks the end of a word with "</w>"; single letters make every word tokenisable.
    tokens = ["!"] + letters + [c + "</w>" for c in letters] + [w + "</w>" for w in WORDS]
    merges: list[str] = []
    for word in WORDS:  # merges that build each whole word left to right: w o r d</w>
        pieces = list(word[:-1]) + [word[-1] + "</w>"]
        while len(pieces) > 1:
            merges.append(f"{pieces[0]} {pieces[1]}")
            pieces = [pieces[0] + pieces[1]] + pieces[2:]
            if pieces[0] not in tokens:
                tokens.append(pieces[0])
    merges = list(dict.fromkeys(merges))
    tokens += ["<|startoftext|>", "<|endoftext|>"]
    tokenizer = CLIPTokenizer(
        vocab={token: i for i, token in enumerate(tokens)},
        merges=[tuple(merge.split()) for merge in merges],
        pad_token="!",
        model_max_length=16,
    )

    config = Owlv2Config(
        text_config={
            "vocab_size": len(tokens),
            "hidden_size": 16,
            "intermediate_size": 32,
            "num_hidden_layers": 1,
            "num_attention_heads": 2,
            "max_position_embeddings": 16,
            "pad_token_id": 0,
            "bos_token_id": len(tokens) - 2,
            "eos_token_id": len(tokens) - 1,
        },
        vision_config={
            "hidden_size": 16,
            "intermediate_size": 32,
            "num_hidden_layers": 1,
            "num_attention_heads": 2,
            "image_size": 64,
            "patch_size": 16,
        },
        projection_dim=16,
    )
    torch.manual_seed(seed)
    model = Owlv2ForObjectDetection(config).eval()
    processor = Owlv2ImageProcessorPil(size={"height": 64, "width": 64})
    model.save_pretrained(folder)
    processor.save_pretrained(folder)
    tokenizer.save_pretrained(folder)
    return folder
